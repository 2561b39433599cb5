//! GRBL 1.1 status reports (`<State|MPos:…|WCO:…|Pn:…>`), as its interface document describes
//! them: the position is MPos or WPos as `$10` asks, in mm or inches as `$13` asks, and the work
//! coordinate offset (`WCO:`) comes only in some reports, so the host keeps the last one.

/// One parsed report, numbers in the report's own unit (mm, or inches with `$13=1`).
#[derive(Debug, Clone, PartialEq)]
pub struct Report {
    /// `Idle`, `Run`, `Hold:0`, `Alarm`, …
    pub state: String,
    /// X, Y as reported.
    pub pos: [f64; 2],
    /// `true`: machine position (MPos); `false`: work position (WPos = MPos − WCO).
    pub machine: bool,
    /// The work coordinate offset, when this report carries one.
    pub wco: Option<[f64; 2]>,
    /// Closed input pins (`Pn:XYZ…`).
    pub pins: String,
}

/// The states GRBL 1.1 reports (with an optional `:n` sub-state).
const STATES: [&str; 9] = [
    "Idle", "Run", "Hold", "Jog", "Alarm", "Door", "Check", "Home", "Sleep",
];

fn xy(field: &str) -> Option<[f64; 2]> {
    let mut it = field.split(',').map(|x| x.trim().parse::<f64>().ok());
    let x = it.next()??;
    let y = it.next()??;
    // Every further axis (Z, A, …) must still be a number: a garbled report is refused whole.
    for v in it {
        v?;
    }
    (x.is_finite() && y.is_finite()).then_some([x, y])
}

/// Parses one report line; `None` for anything malformed (it carries no checksum, so a report
/// that is not exactly well formed is not believed at all).
pub fn parse(line: &str) -> Option<Report> {
    let body = line.strip_prefix('<')?.strip_suffix('>')?;
    let mut fields = body.split('|');
    let state = fields.next()?.to_string();
    let name = state.split(':').next()?;
    if !STATES.contains(&name) {
        return None;
    }
    let (mut pos, mut machine, mut wco, mut pins) = (None, true, None, String::new());
    for f in fields {
        if let Some(p) = f.strip_prefix("MPos:") {
            pos = Some(xy(p)?);
            machine = true;
        } else if let Some(p) = f.strip_prefix("WPos:") {
            pos = Some(xy(p)?);
            machine = false;
        } else if let Some(p) = f.strip_prefix("WCO:") {
            wco = Some(xy(p)?);
        } else if let Some(p) = f.strip_prefix("Pn:") {
            pins = p.to_string();
        }
    }
    Some(Report {
        state,
        pos: pos?,
        machine,
        wco,
        pins,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reports_of_every_documented_shape() {
        let r = parse("<Idle|MPos:-1.000,-2.500,0.000|FS:0,0|Pn:XY>").unwrap();
        assert_eq!(
            (r.state.as_str(), r.pos, r.machine, r.wco, r.pins.as_str()),
            ("Idle", [-1.0, -2.5], true, None, "XY")
        );
        let r =
            parse("<Hold:0|WPos:10.0000,0.5000,0.0000|FS:0,0|WCO:-3.0000,1.2500,0.0000>").unwrap();
        assert_eq!(
            (r.state.as_str(), r.pos, r.machine, r.wco),
            ("Hold:0", [10.0, 0.5], false, Some([-3.0, 1.25]))
        );
        // GRBL 0.9's and 1.1's two-axis builds print two numbers.
        assert_eq!(parse("<Run|MPos:1,2|FS:500,0>").unwrap().pos, [1.0, 2.0]);
        for bad in [
            "<Idxe|MPos:0,0,0>",
            "<Idle|MPos:0,x,0>",
            "<Idle|MPos:0,0,q>",
            "<Idle|FS:0,0>",
            "<Idle|MPos:nan,0,0>",
            "<Idle|MPos:inf,0,0>",
            "<Idle|WPos:0,0,0|WCO:1>",
            "Idle|MPos:0,0,0",
            "<Idle|MPos:1e999,0,0>",
        ] {
            assert!(parse(bad).is_none(), "{bad}");
        }
    }
}

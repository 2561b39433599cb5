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

/// Whether a soft reset in `state` keeps the position: GRBL's reset kills the steppers, raising
/// ALARM:3 (position lost), only in a motion state (motion_control.c's mc_reset: Run, Jog,
/// Home, or a hold still decelerating). Interface.md's sub-states: `Hold:0` "hold complete,
/// ready to resume", `Hold:1` "hold in-progress, reset will throw an alarm", `Door:0` and
/// `Door:1` stopped, `Door:2` and `Door:3` moving.
pub fn still(state: &str) -> bool {
    matches!(
        state,
        "Idle" | "Hold:0" | "Door:0" | "Door:1" | "Alarm" | "Check" | "Sleep"
    )
}

/// Whether GRBL in `state` reads no line: a hold or a door suspends its main loop
/// (protocol_exec_rt_suspend) until cycle start (`~`) or a reset, and sleep until a reset.
pub fn suspended(state: &str) -> bool {
    let name = state.split(':').next().unwrap_or("");
    matches!(name, "Hold" | "Door" | "Sleep")
}

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
        assert!(still("Hold:0") && still("Idle") && still("Alarm") && still("Door:1"));
        assert!(!still("Hold:1") && !still("Run") && !still("Jog") && !still("Door:2"));
        assert!(suspended("Hold:0") && suspended("Hold:1") && suspended("Door:0"));
        assert!(!suspended("Idle") && !suspended("Run") && !suspended("Alarm"));
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

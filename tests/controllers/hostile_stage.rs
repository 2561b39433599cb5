//! Hostile inputs to `rig stage`: absurd flags, targets and controller settings. Every case must
//! end by itself within seconds, under a 4 GiB address-space limit, with the documented exit
//! code and a message that names the flag or setting (and its range) - never a panic, an abort
//! or a hang. Nothing is sent to the controller for a refused target (exit 3).

use crate::common;

fn case(args: &[&str], want_code: i32, must_say: &[&str]) {
    let mut cmd = common::rig();
    cmd.args(["stage", "--sim", "--sim-time-scale", "0"])
        .args(args);
    let h = common::run_hostile(&mut cmd, 4, 30);
    let said = format!("{}{}", h.stdout, h.stderr);
    assert_eq!(h.code, Some(want_code), "{args:?}: {said}");
    for m in must_say {
        assert!(said.contains(m), "{args:?}: missing {m:?} in {said}");
    }
}

fn absurd_flags_are_usage_errors_naming_the_flag_and_range() {
    for (args, flag) in [
        (&["--speed", "nan", "status"][..], "--speed"),
        (&["--speed=-1", "status"][..], "--speed"),
        (&["--speed", "1e308", "status"][..], "--speed"),
        (&["--timeout", "inf", "status"][..], "--timeout"),
        (&["--timeout", "0", "status"][..], "--timeout"),
        (
            &["--timeout-factor", "1e300", "status"][..],
            "--timeout-factor",
        ),
        (&["--timeout-margin=-5", "status"][..], "--timeout-margin"),
        (&["--tolerance-um", "0", "status"][..], "--tolerance-um"),
        (&["--overshoot-um", "1e308", "status"][..], "--overshoot-um"),
        (
            &["--sim-time-scale", "nan", "status"][..],
            "--sim-time-scale",
        ),
    ] {
        case(args, 2, &[flag]);
    }
}

fn absurd_targets_are_refused_before_anything_is_sent() {
    for args in [
        &["move", "1e308", "10"][..],
        &["move", "--", "-1e308", "10"][..],
        &["move", "nan", "10"][..],
        &["move", "10", "inf"][..],
        &["move", "--relative", "1e300", "0"][..],
        &["--dialect", "grbl", "move", "251", "10"][..],
        &["--dialect", "grbl", "move", "nan", "nan"][..],
    ] {
        case(args, 3, &["nothing was sent"]);
    }
    // A jog is clipped to the limits, never sent beyond them; an absurd one goes to the edge.
    case(&["jog", "1e308", "0"], 0, &["jogged to"]);
    case(&["jog", "nan", "0"], 0, &["jogged to"]);
}

fn absurd_controller_settings_are_refused_by_name() {
    for (setting, name) in [
        ("110=0", "$110"),
        ("111=-1", "$111"),
        ("120=0", "$120"),
        ("121=1e30", "$121"),
        ("130=1e9", "$130"),
        ("131=0", "$131"),
        ("24=0", "$24"),
        ("25=-600", "$25"),
        ("27=1e6", "$27"),
        ("23=1e9", "$23"),
        ("10=-1", "$10"),
    ] {
        case(
            &["--dialect", "grbl", "--sim-grbl-setting", setting, "status"],
            8,
            &[name, "allowed range"],
        );
    }
}

fn absurd_native_settings_are_refused_by_name() {
    for (setting, name) in [
        ("MaxSpeed=0", "MaxSpeed"),
        ("MaxSpeed=-5", "MaxSpeed"),
        ("Accel=0", "Accel"),
        ("TravelX=0", "TravelX"),
        ("TravelY=-1000", "TravelY"),
        ("SoftMaxX=0", "SoftMin/SoftMax"),
    ] {
        case(
            &["--sim-native-setting", setting, "status"],
            8,
            &[name, "allowed range"],
        );
    }
}

crate::waiting_tests!(
    absurd_flags_are_usage_errors_naming_the_flag_and_range,
    absurd_targets_are_refused_before_anything_is_sent,
    absurd_controller_settings_are_refused_by_name,
    absurd_native_settings_are_refused_by_name,
);

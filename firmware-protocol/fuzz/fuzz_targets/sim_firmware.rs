//! Arbitrary bytes from a hostile host into both simulated firmwares: no panic, and the stage
//! never leaves its travel by more than the switches allow.
#![no_main]
use libfuzzer_sys::fuzz_target;
use rig_sim::faults::FaultSpec;
use rig_sim::grbl::GrblFirmware;
use rig_sim::native::NativeFirmware;
use rig_sim::rng::Rng;
use rig_sim::stage::{Stage, StageConfig};

fuzz_target!(|data: &[u8]| {
    for home_dir in [-1.0, 1.0] {
        let cfg = StageConfig::new(&mut Rng::new(1), home_dir);
        let mut stage = Stage::new(cfg, FaultSpec::default(), 1, true);
        let mut out = Vec::new();
        let mut events = Vec::new();
        if home_dir < 0.0 {
            let mut fw = NativeFirmware::new(&stage, 1);
            for chunk in data.chunks(7) {
                fw.on_bytes(chunk, &mut stage, &mut out);
                let t = stage.next_event_time().unwrap_or(stage.t);
                stage.advance(t, &mut events);
                for e in events.drain(..) {
                    fw.on_event(e, &mut stage, &mut out);
                }
            }
        } else {
            let mut fw = GrblFirmware::new(&stage, &mut out);
            for chunk in data.chunks(7) {
                fw.on_bytes(chunk, &mut stage, &mut out);
                let t = stage.next_event_time().unwrap_or(stage.t);
                stage.advance(t, &mut events);
                for e in events.drain(..) {
                    fw.on_event(e, &mut stage, &mut out);
                }
            }
        }
        for k in 0..2 {
            let c = stage.carriage(k);
            let [lo, hi] = stage.cfg.switch_um[k];
            assert!(c > lo - 100.0 && c < hi + 100.0, "axis {k} at {c}");
        }
    }
});

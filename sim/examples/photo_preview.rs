//! Writes a preview of the simulator's aerial photo (PGM, 0.25 mm per pixel) to look at.
use rig_sim::scene::{jacksboro, AerialPhoto};
fn main() {
    let number: u32 = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(1);
    let out = std::env::args().nth(2).unwrap_or("photo.pgm".into());
    let t = std::time::Instant::now();
    let p = AerialPhoto::new(jacksboro(), 1, number, 101.0);
    eprintln!("grid {:.2} s; {:?}", t.elapsed().as_secs_f64(), p.exterior);
    let n = 800;
    let mut px = Vec::new();
    let t = std::time::Instant::now();
    for j in 0..n {
        for i in 0..n {
            let u = -100.0 + 200.0 * (i as f64 + 0.5) / n as f64;
            let v = 100.0 - 200.0 * (j as f64 + 0.5) / n as f64;
            px.push((p.transmittance([u, v]) * 255.0) as u8);
        }
    }
    eprintln!(
        "{:.0} ns per pixel",
        t.elapsed().as_nanos() as f64 / (n * n) as f64
    );
    let mut f = format!("P5 {n} {n} 255\n").into_bytes();
    f.extend(px);
    std::fs::write(out, f).unwrap();
}

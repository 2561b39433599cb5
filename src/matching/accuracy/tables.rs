//! The accuracy analysis of seed 002 (Tables 10-12): matched heights against a reference
//! (a truth DEM or check points), in four versions - with and without the bias (the mean
//! difference), with and without the blunders (differences beyond mean ± 3·σ, removed one at
//! a time and the mean and σ recomputed until none is left) - each as RMS, maximum, mean and
//! standard deviation of |ΔZ|, in metres and per mille of the flying height; the blunders the
//! matcher detected and those it did not; and the estimated precision against the true
//! error.

use serde::{Deserialize, Serialize};

/// One version's figures (seed 002, Table 11).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Version {
    pub points: usize,
    pub rms_m: f64,
    pub max_abs_m: f64,
    pub mean_abs_m: f64,
    /// The standard deviation of |ΔZ| (so that RMS² = mean² + σ², as in the seed's table).
    pub sd_abs_m: f64,
    pub rms_permille: f64,
    pub max_abs_permille: f64,
    pub mean_abs_permille: f64,
    pub sd_abs_permille: f64,
}

/// The estimated precision against the true error (without bias and blunders).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PrecisionCheck {
    pub points: usize,
    /// RMS of the estimated σ's, m.
    pub rms_sigma_m: f64,
    /// RMS of (true error / estimated σ): 1 when the σ's are honest.
    pub rms_ratio: f64,
    /// The same with the bias kept: the one to read when the σ's include an error common
    /// to many points (a resected orientation's), which the bias would otherwise remove.
    #[serde(default)]
    pub rms_ratio_with_bias: f64,
    /// Share of the errors within 2σ, % (95.4 for honest Gaussian σ's).
    pub within_2_sigma_percent: f64,
}

/// The whole analysis.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Accuracy {
    /// Flying height above the terrain the per mille figures refer to, m.
    pub flying_height_m: f64,
    /// A blunder lies at least this far from the mean, m.
    pub blunder_floor_m: f64,
    /// Mean difference (matched − reference) of all points, and of the points without the
    /// blunders, m.
    pub bias_m: f64,
    pub bias_without_blunders_m: f64,
    /// Seed 002's versions 1-4: without bias and blunders, without bias with blunders, with
    /// bias without blunders, with bias and blunders.
    pub versions: [Version; 4],
    /// Points the matcher refused (its blunder tests), and their share of all it tried, %.
    pub detected: usize,
    pub detected_percent: f64,
    /// Points the matcher kept that the comparison finds to be blunders, and their share of
    /// all it tried, %.
    pub undetected: usize,
    pub undetected_percent: f64,
    /// The matched points compared (kept by the matcher, with a reference).
    pub compared: usize,
    pub precision: Option<PrecisionCheck>,
}

/// Indices of `d`'s blunders: beyond mean ± 3σ and further than `floor` from the mean, the
/// worst removed first and the mean and σ recomputed until none is left (seed 002: "this was
/// iterated until no blunder was found"). The floor keeps a precise matcher's tail out: seed
/// 002 compared with an operator's heights, 0.2 ‰ apart, where 3σ was a gross error; against
/// an exact reference 3σ can be a few centimetres, which no one calls a blunder.
pub fn blunders_3sigma(d: &[f64], floor: f64) -> Vec<usize> {
    let mut keep: Vec<usize> = (0..d.len()).collect();
    let mut out = Vec::new();
    while keep.len() > 2 {
        let n = keep.len() as f64;
        let mean = keep.iter().map(|&i| d[i]).sum::<f64>() / n;
        let sd = (keep.iter().map(|&i| (d[i] - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
        let (at, worst) = keep
            .iter()
            .enumerate()
            .map(|(k, &i)| (k, (d[i] - mean).abs()))
            .fold((0, -1.0), |a, b| if b.1 > a.1 { b } else { a });
        if worst > 3.0 * sd && worst > floor && sd.is_finite() {
            out.push(keep.remove(at));
        } else {
            break;
        }
    }
    out.sort_unstable();
    out
}

fn version(d: impl Iterator<Item = f64> + Clone, hg: f64) -> Version {
    let a: Vec<f64> = d.map(f64::abs).collect();
    let n = a.len().max(1) as f64;
    let mean = a.iter().sum::<f64>() / n;
    let rms = (a.iter().map(|v| v * v).sum::<f64>() / n).sqrt();
    let sd = (a.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n).sqrt();
    let max = a.iter().copied().fold(0.0, f64::max);
    let pm = |v: f64| 1000.0 * v / hg;
    Version {
        points: a.len(),
        rms_m: rms,
        max_abs_m: max,
        mean_abs_m: mean,
        sd_abs_m: sd,
        rms_permille: pm(rms),
        max_abs_permille: pm(max),
        mean_abs_permille: pm(mean),
        sd_abs_permille: pm(sd),
    }
}

/// The analysis of `diffs` (matched − reference height, m, each with the matcher's σ, m;
/// NaN σ where it gave none) of the points the matcher kept, `refused` the points it
/// refused, `hg` the flying height above the terrain, m; a blunder must also lie `floor_m`
/// from the mean (see [`blunders_3sigma`]).
pub fn analyse(diffs: &[(f64, f64)], refused: usize, hg: f64, floor_m: f64) -> Accuracy {
    let d: Vec<f64> = diffs.iter().map(|p| p.0).collect();
    let bl = blunders_3sigma(&d, floor_m);
    let clean: Vec<usize> = (0..d.len())
        .filter(|i| bl.binary_search(i).is_err())
        .collect();
    let mean = |ix: &mut dyn Iterator<Item = f64>| {
        let (s, n) = ix.fold((0.0, 0usize), |a, v| (a.0 + v, a.1 + 1));
        s / n.max(1) as f64
    };
    let bias_all = mean(&mut d.iter().copied());
    let bias_clean = mean(&mut clean.iter().map(|&i| d[i]));
    let versions = [
        version(clean.iter().map(|&i| d[i] - bias_clean), hg),
        version(d.iter().map(|v| v - bias_all), hg),
        version(clean.iter().map(|&i| d[i]), hg),
        version(d.iter().copied(), hg),
    ];
    let tried = (d.len() + refused).max(1) as f64;
    let with_sigma: Vec<(f64, f64, f64)> = clean
        .iter()
        .map(|&i| (d[i] - bias_clean, diffs[i].1, d[i]))
        .filter(|p| p.1.is_finite() && p.1 > 0.0)
        .collect();
    let precision = (!with_sigma.is_empty()).then(|| {
        let n = with_sigma.len() as f64;
        PrecisionCheck {
            points: with_sigma.len(),
            rms_sigma_m: (with_sigma.iter().map(|p| p.1 * p.1).sum::<f64>() / n).sqrt(),
            rms_ratio: (with_sigma.iter().map(|p| (p.0 / p.1).powi(2)).sum::<f64>() / n).sqrt(),
            rms_ratio_with_bias: (with_sigma.iter().map(|p| (p.2 / p.1).powi(2)).sum::<f64>() / n)
                .sqrt(),
            within_2_sigma_percent: 100.0
                * with_sigma.iter().filter(|p| p.0.abs() <= 2.0 * p.1).count() as f64
                / n,
        }
    });
    Accuracy {
        flying_height_m: hg,
        blunder_floor_m: floor_m,
        bias_m: bias_all,
        bias_without_blunders_m: bias_clean,
        versions,
        detected: refused,
        detected_percent: 100.0 * refused as f64 / tried,
        undetected: bl.len(),
        undetected_percent: 100.0 * bl.len() as f64 / tried,
        compared: d.len(),
        precision,
    }
}

impl Accuracy {
    /// The analysis as a readable table (seed 002's Tables 11 and 12).
    pub fn table(&self) -> String {
        let mut s = format!(
            "Matched heights against the reference ({} points; flying height {:.0} m; bias {:+.3} m, {:+.3} m without blunders)\n\n",
            self.compared, self.flying_height_m, self.bias_m, self.bias_without_blunders_m
        );
        s += "version                          points    RMS m  ‰hg   max|ΔZ| m  ‰hg   mean|ΔZ| m ‰hg   sd|ΔZ| m  ‰hg\n";
        let names = [
            "1 without bias, without blunders",
            "2 without bias, with blunders",
            "3 with bias, without blunders",
            "4 with bias, with blunders",
        ];
        for (n, v) in names.iter().zip(&self.versions) {
            s += &format!(
                "{n:<32} {:>6} {:>8.3} {:>5.3} {:>9.3} {:>5.3} {:>10.3} {:>5.3} {:>8.3} {:>5.3}\n",
                v.points,
                v.rms_m,
                v.rms_permille,
                v.max_abs_m,
                v.max_abs_permille,
                v.mean_abs_m,
                v.mean_abs_permille,
                v.sd_abs_m,
                v.sd_abs_permille
            );
        }
        s += &format!(
            "\nblunders detected by the matcher: {} ({:.1} % of the points tried)\nblunders undetected (beyond 3σ and {:.2} m against the reference): {} ({:.2} %)\n",
            self.detected,
            self.detected_percent,
            self.blunder_floor_m,
            self.undetected,
            self.undetected_percent
        );
        if let Some(p) = &self.precision {
            s += &format!(
                "estimated σ against the true error ({} points): RMS σ {:.3} m, RMS(error/σ) {:.2} without the bias ({:.2} with it), {:.1} % within 2σ\n",
                p.points, p.rms_sigma_m, p.rms_ratio, p.rms_ratio_with_bias, p.within_2_sigma_percent
            );
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Twenty differences computed by hand: eighteen of ±0.5 m (nine each), one of +1.0 m and
    /// one of +10.0 m; σ's of 0.5 m throughout, flying height 1000 m.
    ///
    /// All twenty: mean (9·0.5 − 9·0.5 + 1 + 10)/20 = 0.55 m; sample σ: Σ(d − 0.55)² =
    /// 9·0.0025 + 9·1.1025 + 0.2025 + 89.3025 = 99.45, /19 = 5.234, σ = 2.288; 10 − 0.55 =
    /// 9.45, beyond 3·2.288 = 6.86: a blunder. The nineteen left: mean 1/19 = 0.05263, Σ(d − m)² =
    /// 9·0.44744² + 9·0.55263² + 0.94737² = 1.80180 + 2.74861 + 0.89751 = 5.44792, divided
    /// by 18 = 0.30266, σ = 0.55015; the largest, 1 − 0.05263 = 0.947, is below 1.65: none
    /// more.
    ///
    /// Version 4 (with bias, with blunders): |d| = 18 × 0.5, 1, 10: RMS √((4.5 + 1 + 100)/20)
    /// = √5.275 = 2.29674; max 10; mean (9 + 11)/20 = 1.0; sd √(5.275 − 1) = 2.06761.
    /// Version 3 (with bias, without blunders): RMS √(5.5/19) = 0.53803, max 1, mean 10/19 =
    /// 0.52632, sd √(0.28947 − 0.27701) = 0.11163.
    /// Version 1 (without bias 0.05263, without blunders): |d − m| = 9 × 0.44737, 9 × 0.55263,
    /// 0.94737: mean (4.02632 + 4.97368 + 0.94737)/19 = 0.52355, RMS √(5.44792/19) = 0.53547.
    /// Version 2 (without bias 0.55 m, with blunders): max |10 − 0.55| = 9.45, RMS
    /// √(99.45/20) = 2.22991.
    #[test]
    fn the_four_versions_match_the_hand_computed_table() {
        let mut d: Vec<(f64, f64)> = (0..18)
            .map(|i| (if i % 2 == 0 { 0.5 } else { -0.5 }, 0.5))
            .collect();
        d.push((1.0, 0.5));
        d.push((10.0, 0.5));
        let a = analyse(&d, 5, 1000.0, 0.0);
        let only = d.iter().map(|p| p.0).collect::<Vec<_>>();
        assert_eq!(blunders_3sigma(&only, 0.0), vec![19]);
        // A floor above 9.45 m keeps the 10 m difference.
        assert!(blunders_3sigma(&only, 9.5).is_empty());
        assert!((a.bias_m - 0.55).abs() < 1e-12);
        assert!((a.bias_without_blunders_m - 1.0 / 19.0).abs() < 1e-12);
        let close = |a: f64, b: f64| (a - b).abs() < 5e-5;
        let [v1, v2, v3, v4] = a.versions;
        assert_eq!(
            (v1.points, v2.points, v3.points, v4.points),
            (19, 20, 19, 20)
        );
        assert!(close(v4.rms_m, 2.29674) && close(v4.max_abs_m, 10.0));
        assert!(close(v4.mean_abs_m, 1.0) && close(v4.sd_abs_m, 2.06761));
        assert!(close(v3.rms_m, 0.53803) && close(v3.max_abs_m, 1.0));
        assert!(close(v3.mean_abs_m, 0.52632) && close(v3.sd_abs_m, 0.11163));
        assert!(close(v1.rms_m, 0.53547) && close(v1.mean_abs_m, 0.52355));
        assert!(close(v1.max_abs_m, 0.94737));
        assert!(close(v2.rms_m, 2.22991) && close(v2.max_abs_m, 9.45));
        // Per mille of 1000 m: the metres themselves.
        assert!(close(v4.rms_permille, 2.29674));
        // Blunders: 5 refused of 25 tried, 1 undetected.
        assert_eq!((a.detected, a.undetected, a.compared), (5, 1, 20));
        assert!(close(a.detected_percent, 20.0) && close(a.undetected_percent, 4.0));
        // Precision: errors without bias and blunders over σ 0.5: RMS ratio 0.53547/0.5.
        let p = a.precision.unwrap();
        assert!(close(p.rms_ratio, 1.07094) && p.points == 19);
        // With the bias: version 3's RMS over σ, 0.53803/0.5.
        assert!(close(p.rms_ratio_with_bias, 1.07606));
        assert!(close(p.within_2_sigma_percent, 100.0));
        assert!(a.table().contains("1 without bias, without blunders"));
    }
}

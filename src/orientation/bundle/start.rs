//! The block checked (rays, datum, connections, cameras to calibrate) and its start values:
//! the approximations, photos without one resected from control and intersected points, tie
//! points intersected.

use super::*;

/// Start values: each photo's exterior, each point's ground, each ray's status, each point's
/// rays in the adjustment.
pub(super) type Start = (
    Vec<Exterior>,
    Vec<Vector3<f64>>,
    Vec<RayStatus>,
    Vec<Vec<usize>>,
);

/// Each photo's self-calibrated camera, the cameras checked.
pub(super) fn groups(block: &Block) -> Result<Vec<Option<usize>>, BundleError> {
    let mut group = vec![None; block.photos.len()];
    for (g, c) in block.calibrate.iter().enumerate() {
        let bad = |what: String| BundleError::Calibration {
            camera: c.camera.clone(),
            what,
        };
        if c.photos.is_empty() || !c.free.iter().any(|f| *f) {
            return Err(bad("no photos or no parameter to estimate".into()));
        }
        for &i in &c.photos {
            if i >= block.photos.len() || group[i].is_some() {
                return Err(bad(format!(
                    "photo index {i} not in the block or in two cameras"
                )));
            }
            if block.photos[i].interior != block.photos[c.photos[0]].interior {
                return Err(bad(format!(
                    "photo `{}` has another interior than `{}`: one camera, one interior",
                    block.photos[i].id, block.photos[c.photos[0]].id
                )));
            }
            group[i] = Some(g);
        }
    }
    Ok(group)
}

/// Checks the block and finds start values: the approximate orientations, photos without one
/// resected from control and already intersected points, tie points intersected.
pub(super) fn start(block: &Block) -> Result<Start, BundleError> {
    let np = block.photos.len();
    for (k, r) in block.rays.iter().enumerate() {
        if r.photo >= np || r.point >= block.points.len() {
            return Err(BundleError::BadRay {
                ray: k,
                what: "names a photo or point not in the block".into(),
            });
        }
        if !(r.sigma_mm.is_finite() && r.sigma_mm > 0.0 && r.xy.x.is_finite() && r.xy.y.is_finite())
        {
            return Err(BundleError::BadRay {
                ray: k,
                what: format!(
                    "σ {} mm or its coordinates not a positive finite number",
                    r.sigma_mm
                ),
            });
        }
    }
    let status: Vec<RayStatus> = block
        .rays
        .iter()
        .map(|r| match block.points[r.point].role {
            Role::Check { .. } => RayStatus::Check,
            _ => RayStatus::Used,
        })
        .collect();
    // The datum: three control points or more, seen, not in a line.
    let mut seen = vec![0usize; block.points.len()];
    for (r, s) in block.rays.iter().zip(&status) {
        if *s == RayStatus::Used {
            seen[r.point] += 1;
        }
    }
    let control: Vec<(String, GroundM)> = block
        .points
        .iter()
        .enumerate()
        .filter_map(|(j, p)| match p.role {
            Role::Control { ground, .. } if seen[j] > 0 => Some((p.id.clone(), ground)),
            _ => None,
        })
        .collect();
    if control.len() < 3 {
        return Err(BundleError::TooFewControl {
            found: control.len(),
        });
    }
    let n = control.len() as f64;
    let (mx, my) = control
        .iter()
        .fold((0.0, 0.0), |a, (_, g)| (a.0 + g.x / n, a.1 + g.y / n));
    let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
    for (_, g) in &control {
        sxx += (g.x - mx).powi(2);
        sxy += (g.x - mx) * (g.y - my);
        syy += (g.y - my).powi(2);
    }
    let tr = sxx + syy;
    let det = sxx * syy - sxy * sxy;
    let small = 0.5 * tr - (0.25 * tr * tr - det).max(0.0).sqrt();
    if small < 1e-4 * tr {
        return Err(BundleError::ControlInLine {
            ids: control
                .iter()
                .map(|c| c.0.as_str())
                .collect::<Vec<_>>()
                .join(", "),
        });
    }
    // Connectivity: every photo reached from the first through shared points.
    let mut parent: Vec<usize> = (0..np).collect();
    pub(super) fn root(p: &mut [usize], mut i: usize) -> usize {
        while p[i] != i {
            p[i] = p[p[i]];
            i = p[i];
        }
        i
    }
    let mut first_photo = vec![usize::MAX; block.points.len()];
    for (r, s) in block.rays.iter().zip(&status) {
        if *s != RayStatus::Used {
            continue;
        }
        let f = first_photo[r.point];
        if f == usize::MAX {
            first_photo[r.point] = r.photo;
        } else {
            let (a, b) = (root(&mut parent, f), root(&mut parent, r.photo));
            parent[a] = b;
        }
    }
    let mut size = vec![0usize; np];
    for i in 0..np {
        let r = root(&mut parent, i);
        size[r] += 1;
    }
    let main = (0..np).max_by_key(|&i| size[i]).unwrap_or(0);
    for i in 0..np {
        if root(&mut parent, i) != main && np > 1 {
            let with = (0..np)
                .filter(|&k| root(&mut parent, k) == root(&mut parent, i) && k != i)
                .map(|k| format!("`{}`", block.photos[k].id))
                .collect::<Vec<_>>();
            return Err(BundleError::Unconnected {
                id: block.photos[i].id.clone(),
                with: if with.is_empty() {
                    "it stands alone".into()
                } else {
                    format!("it is tied only to {}", with.join(", "))
                },
            });
        }
    }
    // Start values.
    let mut cams: Vec<Option<Exterior>> = block.photos.iter().map(|p| p.approx).collect();
    let mut pts: Vec<Option<Vector3<f64>>> = block
        .points
        .iter()
        .map(|p| match p.role {
            Role::Control { ground, .. } => Some(Vector3::new(ground.x, ground.y, ground.z)),
            _ => None,
        })
        .collect();
    let mut by_point: Vec<Vec<usize>> = vec![Vec::new(); block.points.len()];
    for (k, (r, s)) in block.rays.iter().zip(&status).enumerate() {
        if *s == RayStatus::Used {
            by_point[r.point].push(k);
        }
    }
    loop {
        // Tie points from the photos with a start.
        for j in 0..block.points.len() {
            if pts[j].is_some() || block.points[j].role != Role::Tie {
                continue;
            }
            let rays: Vec<_> = by_point[j]
                .iter()
                .filter_map(|&k| {
                    let r = &block.rays[k];
                    Some((camera(&block.photos[r.photo], cams[r.photo]?), r.xy))
                })
                .collect();
            if rays.len() >= 2 {
                pts[j] = intersect_of(&rays);
            }
        }
        let missing: Vec<usize> = (0..np).filter(|&i| cams[i].is_none()).collect();
        if missing.is_empty() {
            break;
        }
        let mut progress = false;
        let mut worst = (String::new(), 0usize);
        for &i in &missing {
            let obs: Vec<(PhotoMm, GroundM)> = block
                .rays
                .iter()
                .zip(&status)
                .filter(|(r, s)| r.photo == i && **s == RayStatus::Used)
                .filter_map(|(r, _)| {
                    let p = pts[r.point]?;
                    Some((r.xy, GroundM::new(p.x, p.y, p.z)))
                })
                .collect();
            if obs.len() >= 4 {
                if let Ok(r) = resect(&block.photos[i].interior, &obs) {
                    cams[i] = Some(r.exterior);
                    progress = true;
                    continue;
                }
            }
            worst = (block.photos[i].id.clone(), obs.len());
        }
        if !progress {
            return Err(BundleError::NoStart {
                id: worst.0,
                points: worst.1,
            });
        }
    }
    let cams: Vec<Exterior> = cams
        .into_iter()
        .map(|c| c.expect("every photo has a start"))
        .collect();
    // Tie points still without a start (rays from photos found late) and check points: at
    // the block's mean height under the first photo; the adjustment moves them.
    let pts = pts
        .into_iter()
        .enumerate()
        .map(|(j, p)| {
            p.unwrap_or_else(|| {
                let rays: Vec<_> = by_point[j]
                    .iter()
                    .map(|&k| {
                        let r = &block.rays[k];
                        (camera(&block.photos[r.photo], cams[r.photo]), r.xy)
                    })
                    .collect();
                intersect_of(&rays)
                    .unwrap_or_else(|| Vector3::new(cams[0].centre.x, cams[0].centre.y, 0.0))
            })
        })
        .collect();
    Ok((cams, pts, status, by_point))
}

//! One try at laying the incision out in region R: R's boundary (mended where it is not a
//! disk), its chart, the path and the lips in it, and the constrained, refined
//! triangulation. A try ends with R triangulated, with R to grow (mended, or where the
//! refinement split its boundary) and try again, or with an error the region's policy falls
//! back from.

use std::collections::{HashMap, HashSet};

use spade::handles::{FixedFaceHandle, FixedVertexHandle, InnerTag};
use spade::{AngleLimit, Point2, RefinementParameters, Triangulation};

use crate::geometry::TriMesh;
use crate::math::Vec3;

use super::path::IncisionPath;
use super::plane::{
    ArcPolyline, Cdt, V2, cross2, dist_sq_point_segment_2d, nearest_on_segment_2d,
    point_in_polygon, smooth_path,
};
use super::region::{Region, Site};
use super::types::{IncisionError, IncisionParams};
use super::{LIP_ROOM, LIP_TURN_DEG};
use crate::cut::chart::Chart;

/// What a try works from.
pub(super) struct Context<'a> {
    pub mesh: &'a TriMesh,
    pub path: &'a IncisionPath,
    pub site: &'a Site,
    pub params: &'a IncisionParams,
}

/// R triangulated with the lips.
pub(super) struct Layout {
    /// The triangles in R.
    pub in_region: Vec<bool>,
    /// The same, listed.
    pub region: Vec<usize>,
    /// R laid flat.
    pub chart: Chart,
    /// The path in the chart, smoothed.
    pub path2: ArcPolyline,
    /// The blade's track (tip − entry) at each of its points.
    pub tracks: Vec<Vec3>,
    /// Its length in the chart (m).
    pub length: f64,
    /// The lips' spacing (m).
    pub spacing: f64,
    /// R's boundary loop (mesh vertices) and in the chart.
    pub boundary: Vec<u32>,
    pub boundary2: Vec<[f64; 2]>,
    /// R's vertices off its boundary.
    pub interior: Vec<u32>,
    /// The lips in the chart, `m` segments each, and the lens between them.
    pub upper: Vec<[f64; 2]>,
    pub lower: Vec<[f64; 2]>,
    pub lens: Vec<[f64; 2]>,
    /// The half-opening w_o (m).
    pub w_o: f64,
    pub m: usize,
    /// The triangulation, which of its vertices are mesh vertices, the lips' vertices and
    /// the faces the refinement left outside R.
    pub cdt: Cdt,
    pub cdt_to_mesh: HashMap<usize, u32>,
    pub upper_handles: Vec<FixedVertexHandle>,
    pub lower_handles: Vec<FixedVertexHandle>,
    pub excluded: HashSet<FixedFaceHandle<InnerTag>>,
}

/// How a try ended.
pub(super) enum Try {
    /// R is not a disk: it grows onto these (a mend) and is tried again.
    Mend(Vec<usize>),
    /// The refinement split R's boundary: it grows onto the triangles beyond.
    Grow(Vec<usize>),
    /// R triangulated.
    Done(Box<Layout>),
}

/// R's boundary: its loops (directed edges of R whose twin is not in R; one loop for a
/// disk), whether a vertex has two boundary edges leaving it, and those vertices.
struct Loops {
    loops: Vec<Vec<u32>>,
    pinched: bool,
    pinches: Vec<u32>,
}

fn boundary_loops(mesh: &TriMesh, region: &[usize]) -> Loops {
    let mut directed: HashSet<(u32, u32)> = HashSet::new();
    for &t in region {
        let tri = mesh.triangles[t];
        for k in 0..3 {
            directed.insert((tri[k], tri[(k + 1) % 3]));
        }
    }
    let mut next: HashMap<u32, u32> = HashMap::new();
    let mut pinched = false;
    let mut pinches: Vec<u32> = Vec::new();
    // In the region's order, not the set's: at a pinch, which edge `next` keeps decides
    // the loops reported, and a set's order changes from run to run.
    for &t in region {
        let tri = mesh.triangles[t];
        for k in 0..3 {
            let (a, b) = (tri[k], tri[(k + 1) % 3]);
            if !directed.contains(&(b, a)) && next.insert(a, b).is_some() {
                pinched = true;
                pinches.push(a);
            }
        }
    }
    let mut loops = Vec::new();
    let mut seen: HashSet<u32> = HashSet::new();
    let mut starts: Vec<u32> = next.keys().copied().collect();
    starts.sort_unstable();
    for start in starts {
        if seen.contains(&start) {
            continue;
        }
        let mut lp = vec![start];
        seen.insert(start);
        let mut at = next[&start];
        while at != start {
            if !seen.insert(at) || lp.len() > next.len() {
                pinched = true;
                break;
            }
            lp.push(at);
            match next.get(&at) {
                Some(&n) => at = n,
                None => {
                    pinched = true;
                    break;
                }
            }
        }
        loops.push(lp);
    }
    Loops {
        loops,
        pinched,
        pinches,
    }
}

/// Where R is no disk, what mends it: the skin triangles round a vertex where its boundary
/// touches itself, and those beyond the edges of every boundary loop but the outer one (a
/// hole). The outer loop runs counter-clockwise round the most area in the projection; a
/// hole's runs clockwise.
fn mending(ctx: &Context, region: &Region, b: &Loops) -> Vec<usize> {
    let (mesh, site) = (ctx.mesh, ctx.site);
    let loop_area = |lp: &Vec<u32>| {
        (0..lp.len())
            .map(|i| {
                let a = site.frame.project(&mesh.positions[lp[i] as usize]);
                let b = site
                    .frame
                    .project(&mesh.positions[lp[(i + 1) % lp.len()] as usize]);
                cross2(a, b)
            })
            .sum::<f64>()
    };
    let outer = (0..b.loops.len())
        .max_by(|&x, &y| loop_area(&b.loops[x]).total_cmp(&loop_area(&b.loops[y])));
    let mut joining: Vec<usize> = Vec::new();
    for (l, lp) in b.loops.iter().enumerate() {
        if Some(l) == outer {
            continue;
        }
        for i in 0..lp.len() {
            let (a, c) = (lp[i], lp[(i + 1) % lp.len()]);
            joining.extend(site.edge_owner.get(&(c, a)).copied());
        }
    }
    if !b.pinches.is_empty() {
        joining.extend(
            site.edge_owner
                .values()
                .copied()
                .filter(|&t| mesh.triangles[t].iter().any(|v| b.pinches.contains(v))),
        );
    }
    joining.sort_unstable();
    joining.dedup();
    let steep = region.steep_growth();
    joining.retain(|&t| !region.grown[t] && (steep || site.facing_well(mesh, t)));
    joining
}

/// One try at laying the incision out in `region`.
pub(super) fn lay_out(ctx: &Context, region: &Region) -> Result<Try, IncisionError> {
    let (mesh, site) = (ctx.mesh, ctx.site);
    let in_region = region.grown.clone();
    let region_list: Vec<usize> = (0..mesh.triangles.len())
        .filter(|&t| in_region[t])
        .collect();
    let mut b = boundary_loops(mesh, &region_list);
    if (b.pinched || b.loops.len() != 1) && region.mended < 3 {
        let joining = mending(ctx, region, &b);
        if !joining.is_empty() {
            return Ok(Try::Mend(joining));
        }
    }
    if b.pinched || b.loops.len() != 1 {
        return Err(IncisionError::NotDisk {
            loops: b.loops.len(),
            pinched: b.pinched,
        });
    }
    // R laid flat keeping its angles; projected onto n̄'s plane where that fails and R
    // faces n̄ well throughout (it grew into nothing steep), or once charts failed.
    let conformal = region
        .charted()
        .then(|| Chart::conformal(mesh, &region_list, |x| site.frame.project(x)))
        .flatten();
    let chart = match conformal {
        Some(chart) => chart,
        None => {
            if region.grew_steep() {
                return Err(IncisionError::Triangulation(
                    "the region has no chart".into(),
                ));
            }
            Chart::projected(mesh, &region_list, |x| site.frame.project(x))
        }
    };
    let boundary = b.loops.pop().unwrap_or_default();
    let boundary2: Vec<[f64; 2]> = boundary.iter().map(|&v| chart.vertex(v)).collect();
    // The path in the chart, and what follows from its length there.
    let (points2, tracks) = smooth_path(
        &ctx.path
            .samples
            .iter()
            .map(|s| chart.point(mesh, &s.surface))
            .collect::<Vec<_>>(),
        &ctx.path.across,
    );
    let path2 = ArcPolyline::new(points2);
    let length = path2.length();
    let spacing = (0.5 * site.edge).min(0.5 * length).max(1e-6);
    // The whole path must lie inside R, with room for the lips.
    if path2
        .points
        .iter()
        .any(|&p| !point_in_polygon(&boundary2, p))
    {
        return Err(IncisionError::PathOutsideRegion);
    }
    let lips = lay_lips(ctx, &path2, &boundary2, length, spacing);
    let tri = triangulate(
        mesh,
        &chart,
        &region_list,
        &boundary,
        &boundary2,
        &lips,
        spacing,
    )?;
    let Triangulated {
        mut cdt,
        cdt_to_mesh,
        upper_handles,
        lower_handles,
        interior,
    } = tri;
    // Ruppert/Chew refinement. Constraint edges may be split (the lips and R's boundary
    // get extra vertices on them): with them locked, skinny triangles next to them could
    // not be repaired. Splits of R's boundary are carried into the triangles outside R.
    let before = cdt.num_vertices();
    let result = cdt.refine(
        RefinementParameters::<f64>::new()
            .with_angle_limit(AngleLimit::from_deg(ctx.params.refine_angle_deg))
            .exclude_outer_faces(true)
            .with_max_additional_vertices(20 * before + 100),
    );
    if !result.refinement_complete {
        return Err(IncisionError::Triangulation(
            "refinement ran out of Steiner points".into(),
        ));
    }
    let joining = beyond_split_boundary(
        ctx,
        region,
        &cdt,
        &cdt_to_mesh,
        &boundary,
        &boundary2,
        length,
    );
    if !joining.is_empty() {
        return Ok(Try::Grow(joining));
    }
    Ok(Try::Done(Box::new(Layout {
        in_region,
        region: region_list,
        chart,
        path2,
        tracks,
        length,
        spacing,
        boundary,
        boundary2,
        interior,
        upper: lips.upper,
        lower: lips.lower,
        lens: lips.lens,
        w_o: lips.w_o,
        m: lips.m,
        cdt,
        cdt_to_mesh,
        upper_handles,
        lower_handles,
        excluded: result.excluded_faces.iter().copied().collect(),
    })))
}

/// The lips in the chart.
struct Lips {
    upper: Vec<[f64; 2]>,
    lower: Vec<[f64; 2]>,
    lens: Vec<[f64; 2]>,
    w_o: f64,
    m: usize,
}

/// The lips along `path2` in R (boundary `boundary2`): `m` segments each, the half-opening
/// physics.md §5.1 gives, narrowed to stay within [`LIP_ROOM`] of the way to R's boundary.
fn lay_lips(
    ctx: &Context,
    path2: &ArcPolyline,
    boundary2: &[[f64; 2]],
    length: f64,
    spacing: f64,
) -> Lips {
    let depth_max = ctx.path.depth_max;
    let w_wanted = ctx.params.opening_for(length, depth_max);
    // How fast the lips must turn: the path's turning at the lips' own spacing,
    // averaged over it, so that a jog of the entry point (its rest-space mapping hops
    // by a fraction of a millimetre as the tissue gives) does not step the whole lip,
    // and the walls gridded at its step, finely (the tumour's default stroke, 0.2 mm
    // aside within 0.4 mm: 4042 wall triangles for an 8.7 mm cut). The lips still
    // follow the path itself, jog included.
    let turn_rate = path2.averaged(0.5 * spacing).max_turn_rate(spacing);
    // At least eight segments per lip, so that even a short lip turns smoothly.
    // Lip segments no longer than three quarters of the depth either: the walls below are
    // gridded at the lips' spacing with rows about as tall, and a shallow wall under long
    // segments would be all slivers.
    // And short enough on a curved path that a lip turns by at most LIP_TURN_DEG from
    // one segment to the next (`turn_rate`, above).
    let turn_step = LIP_TURN_DEG.to_radians() / turn_rate.max(1e-300);
    let lip_step = spacing
        .min((0.75 * depth_max).max(0.25 * spacing))
        .min(turn_step.max(0.25 * spacing));
    let m = ((length / lip_step).ceil() as usize).clamp(8, 400);
    // Room for the lips: at every point of the path the lip stays within 0.45 of the
    // way to R's boundary. The parabola is scaled as a whole to fit where it binds, so
    // its shape is kept; near the ends it is narrow, and so may R be (a stab's slit on
    // a sloping start has a narrow region: a cap by the path's nearest approach to the
    // boundary anywhere narrowed the whole shoulder wound to 2.09 mm for 3.05 wanted).
    let room = |c: [f64; 2]| {
        (0..boundary2.len())
            .map(|i| {
                let (a, b) = (boundary2[i], boundary2[(i + 1) % boundary2.len()]);
                dist_sq_point_segment_2d(c, a, b)
            })
            .fold(f64::INFINITY, f64::min)
            .sqrt()
    };
    // And each boundary vertex against the lip beside it: one poking in between two
    // lip steps (where a steep triangle was left out) is nearer the lip there than
    // to either step's path point.
    let beside = boundary2.iter().filter_map(|&b| {
        let (d_sq, u) = path2
            .points
            .windows(2)
            .zip(path2.arc.windows(2))
            .map(|(w, a)| {
                let (t, d_sq) = nearest_on_segment_2d(b, w[0], w[1]);
                (d_sq, a[0] + t * (a[1] - a[0]))
            })
            .min_by(|p, q| p.0.total_cmp(&q.0))?;
        let x = u / length;
        (x > 0.0 && x < 1.0).then(|| LIP_ROOM * d_sq.sqrt() / (4.0 * x * (1.0 - x)))
    });
    let w_o = (1..m)
        .map(|r| {
            let x = r as f64 / m as f64;
            LIP_ROOM * room(path2.at(x * length)) / (4.0 * x * (1.0 - x))
        })
        .chain(beside)
        .fold(w_wanted, f64::min)
        .max(0.0);
    let mut upper = Vec::with_capacity(m + 1);
    let mut lower = Vec::with_capacity(m + 1);
    for r in 0..=m {
        let u = length * r as f64 / m as f64;
        let c = path2.at(u);
        let tau = path2.tangent(u, 0.5 * spacing);
        let nu = [-tau[1], tau[0]];
        let x = u / length;
        let w = 4.0 * w_o * x * (1.0 - x);
        upper.push([c[0] + w * nu[0], c[1] + w * nu[1]]);
        lower.push([c[0] - w * nu[0], c[1] - w * nu[1]]);
    }
    let mut lens: Vec<[f64; 2]> = upper.clone();
    lens.extend(lower[1..m].iter().rev());
    Lips {
        upper,
        lower,
        lens,
        w_o,
        m,
    }
}

/// The triangulation of R with the lips, before refinement.
struct Triangulated {
    cdt: Cdt,
    cdt_to_mesh: HashMap<usize, u32>,
    upper_handles: Vec<FixedVertexHandle>,
    lower_handles: Vec<FixedVertexHandle>,
    interior: Vec<u32>,
}

/// The constrained triangulation of R (its boundary, its vertices off the lens, the lips)
/// with R's boundary and the lips as constraints.
fn triangulate(
    mesh: &TriMesh,
    chart: &Chart,
    region: &[usize],
    boundary: &[u32],
    boundary2: &[[f64; 2]],
    lips: &Lips,
    spacing: f64,
) -> Result<Triangulated, IncisionError> {
    let Lips {
        upper,
        lower,
        lens,
        m,
        ..
    } = lips;
    let m = *m;
    let near_lens = |p: [f64; 2]| {
        point_in_polygon(lens, p)
            || (0..lens.len()).any(|i| {
                dist_sq_point_segment_2d(p, lens[i], lens[(i + 1) % lens.len()])
                    < 0.25 * spacing * spacing
            })
    };
    let mut cdt = Cdt::new();
    let mut cdt_to_mesh: HashMap<usize, u32> = HashMap::new();
    let insert = |cdt: &mut Cdt, p: [f64; 2]| {
        cdt.insert(V2(Point2::new(p[0], p[1])))
            .map_err(|e| IncisionError::Triangulation(format!("{e:?}")))
    };
    let mut boundary_handles = Vec::with_capacity(boundary.len());
    for (k, &v) in boundary.iter().enumerate() {
        let h = insert(&mut cdt, boundary2[k])?;
        cdt_to_mesh.insert(h.index(), v);
        boundary_handles.push(h);
    }
    let on_boundary: HashSet<u32> = boundary.iter().copied().collect();
    let region_vertices: HashSet<u32> = region.iter().flat_map(|&t| mesh.triangles[t]).collect();
    let mut interior: Vec<u32> = region_vertices
        .iter()
        .copied()
        .filter(|v| !on_boundary.contains(v))
        .collect();
    interior.sort_unstable();
    for &v in &interior {
        let p = chart.vertex(v);
        if !near_lens(p) {
            let h = insert(&mut cdt, p)?;
            cdt_to_mesh.insert(h.index(), v);
        }
    }
    let mut upper_handles = Vec::with_capacity(m + 1);
    let mut lower_handles = Vec::with_capacity(m + 1);
    for r in 0..=m {
        let hu = insert(&mut cdt, upper[r])?;
        upper_handles.push(hu);
        if r == 0 || r == m {
            lower_handles.push(hu);
        } else {
            lower_handles.push(insert(&mut cdt, lower[r])?);
        }
    }
    let constrain = |cdt: &mut Cdt, a, b| {
        if cdt.can_add_constraint(a, b) {
            cdt.add_constraint(a, b);
            Ok(())
        } else {
            Err(IncisionError::Triangulation(
                "a lip crosses the region boundary".into(),
            ))
        }
    };
    for k in 0..boundary_handles.len() {
        let (a, b) = (
            boundary_handles[k],
            boundary_handles[(k + 1) % boundary_handles.len()],
        );
        constrain(&mut cdt, a, b)?;
    }
    for r in 0..m {
        constrain(&mut cdt, upper_handles[r], upper_handles[r + 1])?;
        constrain(&mut cdt, lower_handles[r], lower_handles[r + 1])?;
    }
    Ok(Triangulated {
        cdt,
        cdt_to_mesh,
        upper_handles,
        lower_handles,
        interior,
    })
}

/// The triangles beyond R's boundary edges the refinement split, that R grows onto (while
/// it has grown so fewer than eight times: a scanned liver's 24 mm triangles around a 12 mm
/// cut took more than three), as the policy allows.
fn beyond_split_boundary(
    ctx: &Context,
    region: &Region,
    cdt: &Cdt,
    cdt_to_mesh: &HashMap<usize, u32>,
    boundary: &[u32],
    boundary2: &[[f64; 2]],
    length: f64,
) -> Vec<usize> {
    let (mesh, site) = (ctx.mesh, ctx.site);
    let scale = site.edge.max(length);
    let tol2 = (1e-9 * scale).powi(2);
    let mut split: Vec<usize> = Vec::new();
    for vh in cdt.fixed_vertices() {
        if cdt_to_mesh.contains_key(&vh.index()) {
            continue;
        }
        let p = cdt.vertex(vh).position();
        for k in 0..boundary2.len() {
            let (a, b) = (boundary2[k], boundary2[(k + 1) % boundary2.len()]);
            if dist_sq_point_segment_2d([p.x, p.y], a, b) < tol2 {
                split.push(k);
            }
        }
    }
    let mut joining: Vec<usize> = Vec::new();
    if region.attempt < 8 {
        for &k in &split {
            let (a, b) = (boundary[k], boundary[(k + 1) % boundary.len()]);
            if let Some(&t) = site.edge_owner.get(&(b, a))
                && !region.grown[t]
                && (site.facing_well(mesh, t) || region.steep_growth())
            {
                joining.push(t);
            }
        }
    }
    joining
}

//! The cut surface Σ: grown by the blade's sweep, the pairs it cuts (faded out near the
//! front: crack-front transparency), and the tests against it (near Σ, the crack's share, the
//! blade in its own wound).

use super::*;

/// A neighbour pair whose rest segment crosses Σ near the crack front (physics.md §4.3).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct TransparentPair {
    pub(super) i: u32,
    pub(super) j: u32,
    /// Where the segment crosses Σ (rest).
    pub(super) crossing: Vec3,
    /// The distance added in the kernel now (m).
    pub(super) extra_m: f64,
}

/// What a tick's sweep added to Σ.
pub(super) struct Sweep {
    pub(super) new_sigma: Range<usize>,
    pub(super) slit_rest: Option<Vec3>,
    pub(super) plunge_normal: Option<Vec3>,
    /// The crack front jumped (fracture).
    pub(super) fractured: bool,
}

impl CuttingStage {
    /// Σ grown by the blade's sweep while it cuts: the new triangles, the slit its flat
    /// opened going in point first, and that flat's normal.
    pub(super) fn grow_sigma(
        &mut self,
        force: &CutForce,
        edge_rest: Option<[Vec3; 2]>,
        blade: Option<&Blade>,
        retracing: bool,
        withdrawing: bool,
        jump: Option<f64>,
    ) -> Sweep {
        let sigma_before = self.sigma.triangles.len();
        let front_before = self.last_sweep;
        let mut fractured = false;
        let mut slit_rest = None;
        // While the blade goes in point first, the normal of its flat: the plane that parts
        // left from right when the motion, along the edge, defines none.
        let mut plunge_normal = None;
        match (force.phase, edge_rest) {
            (CutPhase::Cutting, Some([tip, entry])) => {
                // Σ reaches a quarter spacing above the surface, so that no pair or surface
                // vertex near the top sees across it through rounding.
                let up = (entry - tip).try_normalize(1e-12).unwrap_or_else(Vec3::z);
                let edge = [tip, entry + up * (0.25 * self.spacing_m)];
                // Going in point first (within 60° of it), the edge sweeps nothing; the
                // blade's flat slits the tissue behind it.
                let flat = blade
                    .filter(|_| self.direction.dot(&up) < -0.5)
                    .and_then(|b| {
                        (b.toward_back - up * b.toward_back.dot(&up)).try_normalize(1e-6)
                    });
                // Left is on the left of a blade cutting edge first (toward −back).
                plunge_normal = flat.map(|back| back.cross(&up));
                let at = self.steady.position();
                // Cutting edge first, the crack front advances by fracture (`fracture`); in
                // point first, the flat's slit follows the blade.
                let ahead = blade
                    .and_then(touch::front_ahead)
                    .filter(|_| flat.is_none() && self.force.fracture_by_energy());
                match self.last_sweep {
                    // A crack front is material: a blade whose edge reads as in its own cut
                    // (the lips it pushes are mapped there) leaves it where it is.
                    Some(_) if retracing && ahead.is_some() => {}
                    // Moving back along its cut the blade is on Σ: the sweep goes on from
                    // here when it cuts again (from where it was, one straight quad would
                    // cut the chord of a curved cut).
                    _ if retracing => (self.last_sweep, self.last_sweep_at) = (Some(edge), at),
                    // Pulling out opens nothing new; the sweep resumes from where it
                    // stopped.
                    _ if withdrawing => {}
                    None => (self.last_sweep, self.last_sweep_at) = (Some(edge), at),
                    // The edge jitters with the device's noise, and would sweep Σ to and
                    // fro around a held blade: the blade must also have moved steadily.
                    Some(last) => {
                        let target = match ahead {
                            Some(ahead) => {
                                // By energy, or taken to the edge by the slip rule: the
                                // crack advances either way.
                                let target = self.front_target(&last, &edge, ahead, jump);
                                fractured = target.is_some();
                                target
                            }
                            None => (self.moved_enough(&last, &edge)
                                && self.moved_steadily_since(self.last_sweep_at))
                            .then_some(edge),
                        };
                        if let Some(target) = target {
                            self.sigma.add_sweep(last[0], last[1], target[0], target[1]);
                            if let Some(back) = flat {
                                let width = self.tool.blade_width_m;
                                self.sigma.add_blade_flat(target[0], target[1], back, width);
                                slit_rest = Some(back * (entry - tip).norm().min(width));
                            }
                            (self.last_sweep, self.last_sweep_at) = (Some(target), at);
                        }
                    }
                }
            }
            _ => (self.last_sweep, self.last_sweep_at) = (None, None),
        }
        // A front that moved needs its samples again.
        if self.last_sweep != front_before {
            self.front.stale = true;
        }
        Sweep {
            new_sigma: sigma_before..self.sigma.triangles.len(),
            slit_rest,
            plunge_normal,
            fractured,
        }
    }

    /// The pairs the new Σ triangles cross cut (or, near the front, faded out), and the
    /// points whose rows changed refitted and woken (`apply_topology`). Returns the pairs
    /// removed.
    pub(super) fn cut_pairs(
        &mut self,
        new_sigma: Range<usize>,
        solver: &mut Solver,
        neighbours: &mut Neighbourhoods,
        grid: &RestGrid,
    ) -> usize {
        let mut pairs_removed = 0;
        self.changed.clear();
        let fade_m = 0.5 * self.transparency * self.kernel.support_m;
        let material = self.material_points as u32;
        let mut body_pairs_removed = 0;
        let front = self.last_sweep;
        for t in new_sigma.clone() {
            let (transparent, changed) = (&mut self.transparent, &mut self.changed);
            visit_crossing_pairs(
                &self.sigma.triangles[t],
                solver.rest(),
                grid,
                neighbours,
                self.kernel.support_m,
                &mut self.candidates,
                |neighbours, i, j, crossing| {
                    // Near the front a body pair fades out as the blade moves on (below);
                    // a virtual point's pair is cut at once (the node is released anyway),
                    // and so is one crossing as far behind the edge as a pair is faded out
                    // (the back of a stab's slit, up to a blade width behind it).
                    let body = i < material && j < material;
                    let behind = front.is_some_and(|[a, b]| {
                        distance_sq_to_segment(&crossing, &a, &b) >= fade_m * fade_m
                    });
                    if body && fade_m > 0.0 && !behind && transparent.len() < MAX_TRANSPARENT_PAIRS
                    {
                        if !transparent.iter().any(|p| p.i == i && p.j == j) {
                            transparent.push(TransparentPair {
                                i,
                                j,
                                crossing,
                                extra_m: 0.0,
                            });
                        }
                        return false;
                    }
                    neighbours.remove(i as usize, j);
                    neighbours.remove(j as usize, i);
                    changed.extend([i, j]);
                    pairs_removed += 1;
                    body_pairs_removed += usize::from(body);
                    true
                },
            );
        }
        // The front moved: fade the pairs within its reach. Pairs left by an earlier
        // stroke, out of reach, keep the weight they have (a finished incision's crack tip
        // stays partly connected) until a front comes by again.
        if let (Some(front), false) = (self.last_sweep, new_sigma.is_empty()) {
            let faded = self.fade_transparent_pairs(&front, solver.rest(), neighbours);
            pairs_removed += faded;
            body_pairs_removed += faded;
        }
        // Unique changed points, in the order first seen, refitted and all of them awake.
        let mut write = 0;
        for r in 0..self.changed.len() {
            let i = self.changed[r];
            if !std::mem::replace(&mut self.changed_flag[i as usize], true) {
                self.changed[write] = i;
                write += 1;
            }
        }
        self.changed.truncate(write);
        for &i in &self.changed {
            self.changed_flag[i as usize] = false;
        }
        let changed = std::mem::take(&mut self.changed);
        super::super::apply_topology(&changed, solver, neighbours, |i| self.wake(i));
        self.changed = changed;
        self.pairs_removed_total += body_pairs_removed;
        pairs_removed
    }

    /// Whether the blade's tip is down in the wound it has cut (below the last entry and
    /// under it, within the exit margin): the lips have parted around the blade there, so
    /// no surface is near the tip, yet it is in the tissue.
    pub(super) fn in_own_wound(&self, b: &Blade) -> bool {
        self.last_entry.is_some_and(|(entry, ..)| {
            let d = entry - b.tip;
            let below = d.dot(&b.edge);
            // The tip below the entry, the back above it: the edge spans the surface.
            below > 0.0
                && (entry - b.back).dot(&b.edge) < 0.0
                && (d - b.edge * below).norm() <= self.exit_margin_m
        })
    }

    /// Transparency near the crack front (physics.md §4.3, Organ et al. 1996): a pair that
    /// crosses Σ at distance d_s from the front (the blade's edge) weighs as if it were
    /// h·(2d_s/κh)² farther apart, so it fades out over κh/2 of travel instead of switching
    /// off in one tick — hard visibility makes a spurious discontinuity ahead of the crack
    /// and the points there jerk as their pairs switch off one by one. Fully faded pairs are
    /// removed; the rest get their new weight. Returns the pairs removed.
    pub(super) fn fade_transparent_pairs(
        &mut self,
        front: &[Vec3; 2],
        rest: &[Vec3],
        neighbours: &mut Neighbourhoods,
    ) -> usize {
        let h = self.kernel.support_m;
        let kappa_h = self.transparency * h;
        // A pair is faded out by the time the front is κh/2 past its crossing; one farther
        // away than that (and a support radius more) belongs to another front.
        let reach = 0.5 * kappa_h + h;
        let mut removed = 0;
        let mut r = 0;
        while r < self.transparent.len() {
            let pair = self.transparent[r];
            let (i, j) = (pair.i as usize, pair.j);
            let d_s = distance_sq_to_segment(&pair.crossing, &front[0], &front[1]).sqrt();
            if d_s > reach {
                r += 1;
                continue;
            }
            // Only ever more transparent: a front that turns back does not re-join a pair.
            let extra = (h * (2.0 * d_s / kappa_h).powi(2)).max(pair.extra_m);
            if (rest[i] - rest[j as usize]).norm() + extra >= h {
                // Faded out: the pair is cut.
                neighbours.remove(i, j);
                neighbours.remove(j as usize, pair.i);
                removed += 1;
                self.transparent.swap_remove(r);
                self.changed.extend([pair.i, j]);
                continue;
            }
            // Rows are rebuilt only when the weight moved by more than rounding.
            if extra - pair.extra_m > 1e-9 * h {
                neighbours.set_extra(i, j, extra);
                self.transparent[r].extra_m = extra;
                self.changed.extend([pair.i, j]);
            }
            r += 1;
        }
        removed
    }

    pub(super) fn moved_enough(&self, last: &[Vec3; 2], edge: &[Vec3; 2]) -> bool {
        let step = SWEEP_FRACTION_OF_SPACING * self.spacing_m;
        (edge[0] - last[0]).norm() >= step || (edge[1] - last[1]).norm() >= step
    }

    /// Whether the blade's steady point has moved a sweep step since it was at `from`.
    pub(super) fn moved_steadily_since(&self, from: Option<Vec3>) -> bool {
        let step = SWEEP_FRACTION_OF_SPACING * self.spacing_m;
        match (self.steady.position(), from) {
            (Some(at), Some(from)) => (at - from).norm() >= step,
            _ => true,
        }
    }

    /// Whether `x` (rest) lies on Σ, within the blade's thickness and a quarter spacing.
    pub(super) fn near_sigma(&self, x: &Vec3) -> bool {
        self.sigma
            .triangles
            .iter()
            .any(|tri| self.near_triangle(x, tri))
    }

    /// How much new crack the blade opens per unit of its motion, as a share of its depth
    /// (0–1): what its edge sweeps and what its tip slits, added in quadrature (a pointed
    /// blade, whose slit narrows to the tip, would open about the larger, a rectangular one
    /// their sum; in between, a corner from plunging to cutting forward neither dips nor
    /// bulges).
    ///
    /// * The edge, moving across itself, sweeps its depth × the sine of its angle to the
    ///   motion — a raked blade (a scalpel held at 45°) cuts the vertical depth, not the
    ///   length of edge in the tissue — times the share of it in uncut tissue: the edge is
    ///   moved ahead by two in-plane tolerances and sampled.
    /// * The tip, moving tip first, slits the tissue ahead of it as wide as the blade is
    ///   in it — its depth, at most the blade's width (a blade whose tip tapers at about
    ///   45°) — × the cosine, if the point two in-plane tolerances ahead of it is uncut.
    ///
    /// A point is cut already if it lies on a part of Σ that runs along the motion, within
    /// the contact tolerance across that part (a hand does not retrace a cut exactly) but
    /// within the in-plane tolerance of its extent, so that the end of a cut, or the floor
    /// of a shallower one, is found to within about a millimetre. (Forward, the samples are
    /// ahead of Σ's front, which is at most a sweep step behind the edge. An older cut the
    /// blade crosses faces the motion and does not count.)
    pub(super) fn crack_share(&mut self, tip: Vec3, entry: Vec3) -> f64 {
        let h = self.direction;
        // Not moved yet (a tool that appeared in the tissue): nothing to look ahead along.
        let (Some(along_edge), false) = ((entry - tip).try_normalize(1e-12), h == Vec3::zeros())
        else {
            return 1.0;
        };
        let cos = along_edge.dot(&h);
        let across = h - along_edge * cos;
        let sin = across.norm();
        let tip_first = (-cos).max(0.0);
        let reach = 2.0 * self.sigma_plane_tolerance();
        let (a, b) = if sin > 1e-3 {
            let ahead = across * (reach / sin);
            (tip + ahead, entry + ahead)
        } else {
            (tip, tip)
        };
        let probe = tip + h * reach;
        // The Σ triangles near the moved edge and the tip's probe, once (Σ only grows over
        // a session); past the scratch's capacity, all of them.
        let pad = self.sigma_tolerance() + self.sigma_plane_tolerance();
        let region = Aabb::around([&a, &b, &probe]).expanded(pad);
        let overflow = !near_region(
            &self.sigma.boxes,
            &region,
            &mut self.probe_candidates,
            MAX_PROBE_CANDIDATES,
        );
        let cut = |x: &Vec3, along: &Vec3| {
            let on = |tri: &[Vec3; 3]| self.on_triangle_along(x, tri, along);
            if overflow {
                self.sigma.triangles.iter().any(on)
            } else {
                self.probe_candidates
                    .iter()
                    .any(|&t| on(&self.sigma.triangles[t as usize]))
            }
        };
        let edge = if sin > 1e-3 {
            let fresh = (0..FRESH_SAMPLES)
                .filter(|&k| {
                    !cut(
                        &(a + (b - a) * ((k as f64 + 0.5) / FRESH_SAMPLES as f64)),
                        &across,
                    )
                })
                .count();
            sin * fresh as f64 / FRESH_SAMPLES as f64
        } else {
            0.0
        };
        let slit = if tip_first > 0.0 && !cut(&probe, &h) {
            (self.tool.blade_width_m / (entry - tip).norm()).min(1.0) * tip_first
        } else {
            0.0
        };
        edge.hypot(slit).min(1.0)
    }

    /// Whether `x` (rest) is on `tri`, a part of Σ running along `direction`: within the
    /// contact tolerance of its plane and the in-plane tolerance of its extent.
    pub(super) fn on_triangle_along(&self, x: &Vec3, tri: &[Vec3; 3], direction: &Vec3) -> bool {
        let n = (tri[1] - tri[0]).cross(&(tri[2] - tri[0]));
        let n_len = n.norm();
        if n.dot(direction).abs() >= 0.5 * n_len * direction.norm() {
            return false;
        }
        let off = x - closest_point_on_triangle(x, tri);
        let normal = off.dot(&n) / n_len;
        let in_plane = (off - n * (normal / n_len)).norm();
        normal.abs() <= self.sigma_tolerance() && in_plane <= self.sigma_plane_tolerance()
    }

    /// Whether `x` (rest) is within the contact tolerance of `tri`: the box test first.
    pub(super) fn near_triangle(&self, x: &Vec3, tri: &[Vec3; 3]) -> bool {
        let tol = self.sigma_tolerance();
        Aabb::around(tri).expanded(tol).contains(x)
            && (closest_point_on_triangle(x, tri) - x).norm() <= tol
    }

    /// Contact tolerance: the blade's thickness and a quarter spacing.
    pub(super) fn sigma_tolerance(&self) -> f64 {
        self.tool.blade_thickness_m + 0.25 * self.spacing_m
    }

    /// Tolerance within Σ's plane, where its extent ends (the end of a cut, the floor of a
    /// shallow one): the blade's thickness and a twentieth of a spacing, for the rest map's
    /// wobble between passes and the kinks of a curved sweep.
    pub(super) fn sigma_plane_tolerance(&self) -> f64 {
        self.tool.blade_thickness_m + 0.05 * self.spacing_m
    }
}

/// The triangles whose `boxes` overlap `region`, into `out` (cleared first), at most
/// `most` of them (room made once); `false` when more overlap (then take every triangle).
pub(super) fn near_region(boxes: &[Aabb], region: &Aabb, out: &mut Vec<u32>, most: usize) -> bool {
    out.clear();
    for (t, b) in boxes.iter().enumerate() {
        if b.overlaps(region) {
            if out.len() == most {
                return false;
            }
            out.push(t as u32);
        }
    }
    true
}

//! The dent: before rupture the blade presses the tissue, a displacement-controlled patch of
//! points around its tip held on the blade, released over a short time once it cuts.

use super::*;

/// The dent is a smooth patch this many rupture displacements wide (at least one support
/// radius): a one-point dent deeper than the lattice spacing would invert the cells around
/// it on fine models, while the physical dent spreads over the blade's contact.
pub(super) const DENT_RADIUS_PER_RUPTURE_DISPLACEMENT: f64 = 2.0;

/// After rupture the dent relaxes over this time (s) as the crack opens under the blade,
/// rather than springing back at once: a sudden release of a soft organ's stored dent
/// throws the points around the fresh crack inside out.
pub(super) const DENT_RELEASE_S: f64 = 0.1;

/// Most points in the dent patch (preallocated: the tick does not allocate). A patch of
/// radius 2h holds about 270 lattice points, half of them inside a flat surface.
pub(super) const MAX_DENT_POINTS: usize = 256;

/// A point the blade presses down before the capsule ruptures: it follows the tip by
/// `weight` of the tip's travel since the press began.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Pressed {
    pub(super) point: u32,
    pub(super) start_position: Vec3,
    pub(super) weight: f64,
}

/// The largest radius up to `radius` whose ball about `c` holds at most `most` points: the
/// dent patch of a small organ sampled finely would hold more than its preallocated slots,
/// and cutting the patch off in the grid's order left free points among pressed ones,
/// dragged inside out. Shrinks by the cube root of the excess (a few grid queries, once per
/// press; no allocation).
pub(super) fn radius_holding(
    grid: &RestGrid,
    rest: &[Vec3],
    c: &Vec3,
    radius: f64,
    most: usize,
) -> f64 {
    let mut r = radius;
    for _ in 0..8 {
        let mut inside = 0usize;
        grid.for_each_within(rest, c, r, |_, d2| {
            if d2 < r * r {
                inside += 1;
            }
        });
        if inside <= most {
            return r;
        }
        r *= 0.97 * (most as f64 / inside as f64).cbrt();
    }
    r
}

impl CuttingStage {
    /// Before rupture the blade dents the capsule: the points under the tip follow the blade
    /// (displacement control; the device force comes from the measured loading curve,
    /// which a linear-elastic organ this soft could not reproduce), the nearest fully and
    /// the others of the patch with a smooth fall-off. The dent relaxes over
    /// [`DENT_RELEASE_S`] after rupture or when the blade leaves.
    pub(super) fn press_tissue(
        &mut self,
        now_s: f64,
        force: &CutForce,
        blade: Option<&Blade>,
        edge: Option<[Vec3; 2]>,
        solver: &mut Solver,
        grid: &RestGrid,
    ) {
        let pressing = force.phase == CutPhase::Loading;
        match (pressing, self.press_start, blade, edge) {
            (true, None, Some(b), Some(edge)) => {
                let rest = solver.rest();
                let radius = self.dent_radius_m;
                let mut nearest: Option<(f64, u32)> = None;
                grid.for_each_within(rest, &edge[0], 2.0 * self.kernel.support_m, |k, d2| {
                    if nearest.is_none_or(|(d, _)| d2 < d) {
                        nearest = Some((d2, k));
                    }
                });
                let Some((_, centre)) = nearest else { return };
                let c = rest[centre as usize];
                let radius = radius_holding(grid, rest, &c, radius, MAX_DENT_POINTS);
                let positions = solver.positions();
                // A point the scene's supports fix (bone) is not the dent's to hold or free.
                let fixed = solver.fixed();
                let pressed = &mut self.pressed;
                pressed.clear();
                grid.for_each_within(rest, &c, radius, |k, d2| {
                    let q = 1.0 - d2 / (radius * radius);
                    if q > 0.0
                        && pressed.len() < MAX_DENT_POINTS
                        && !fixed[k as usize].contains(&true)
                    {
                        pressed.push(Pressed {
                            point: k,
                            start_position: positions[k as usize],
                            weight: if k == centre { 1.0 } else { q * q },
                        });
                    }
                });
                for r in 0..self.pressed.len() {
                    let k = self.pressed[r].point;
                    self.wake(k);
                    solver.fix(k as usize, [true; 3]);
                }
                self.press_start = Some(b.tip);
                self.press_travel = Vec3::zeros();
                self.release_start_s = None;
                self.dent_patch = (c, radius);
                self.wake_around_dent(solver.rest(), grid);
            }
            (true, Some(start), Some(b), _) if self.release_start_s.is_none() => {
                // The dent goes in with the blade and back up with it, never out past
                // where the blade touched; sideways it follows (a slide ruptures the
                // capsule within the rupture displacement).
                let travel = b.tip - start;
                let into = travel.dot(&force.direction);
                self.press_travel = travel + force.direction * (into.max(0.0) - into);
                self.hold_dent(1.0, solver);
                self.wake_around_dent(solver.rest(), grid);
            }
            (_, Some(_), _, _) => {
                let since = *self.release_start_s.get_or_insert(now_s);
                let left = 1.0 - (now_s - since) / DENT_RELEASE_S;
                if left > 0.0 {
                    self.hold_dent(left, solver);
                    self.wake_around_dent(solver.rest(), grid);
                } else {
                    for p in &self.pressed {
                        solver.fix(p.point as usize, [false; 3]);
                    }
                    self.pressed.clear();
                    self.press_start = None;
                    self.release_start_s = None;
                }
            }
            _ => {}
        }
    }

    /// Keeps the points within one support radius of the dent patch integrated while it is
    /// held. The affected region around the edge (3 support radii) does not cover a patch two
    /// rupture displacements wide on a fine lattice, and the points left asleep beside it
    /// stayed where they were, taking the patch's whole strain at its rim: on the 12 mm
    /// tumour scan they sprang out inverted, at 1.7 m/s, when rupture woke them.
    pub(super) fn wake_around_dent(&mut self, rest: &[Vec3], grid: &RestGrid) {
        let (c, radius) = self.dent_patch;
        let reach = radius + self.kernel.support_m;
        grid.for_each_within(rest, &c, reach, |k, _| self.wake(k));
    }

    /// Holds the dented points at `fraction` of the dent.
    pub(super) fn hold_dent(&mut self, fraction: f64, solver: &mut Solver) {
        let travel = self.press_travel * fraction;
        for p in &self.pressed {
            self.last_near[p.point as usize] = self.tick;
            solver.set_target(p.point as usize, p.start_position + travel * p.weight);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A lattice of 1 mm spacing, 21³ points: a ball of 6 mm radius holds about 900.
    fn lattice() -> (Vec<Vec3>, RestGrid) {
        let mut rest = Vec::new();
        for z in 0..21 {
            for y in 0..21 {
                for x in 0..21 {
                    rest.push(Vec3::new(x as f64, y as f64, z as f64) * 1e-3);
                }
            }
        }
        let grid = RestGrid::build(&rest, 2e-3);
        (rest, grid)
    }

    fn held(grid: &RestGrid, rest: &[Vec3], c: &Vec3, r: f64) -> usize {
        let mut n = 0;
        grid.for_each_within(rest, c, r, |_, d2| n += usize::from(d2 < r * r));
        n
    }

    /// The dent patch is a whole ball: a radius whose ball holds more points than the slots
    /// shrinks until it holds at most that many (not much fewer), and one that fits is kept.
    #[test]
    fn a_dent_patch_too_large_for_its_slots_shrinks_to_a_whole_ball() {
        let (rest, grid) = lattice();
        let c = Vec3::new(10.0, 10.0, 20.0) * 1e-3; // on a face: half a ball inside
        let r = radius_holding(&grid, &rest, &c, 6e-3, MAX_DENT_POINTS);
        let n = held(&grid, &rest, &c, r);
        println!("radius 6 → {:.2} mm holding {n} points", r * 1e3);
        assert!(held(&grid, &rest, &c, 6e-3) > MAX_DENT_POINTS);
        assert!((MAX_DENT_POINTS / 2..=MAX_DENT_POINTS).contains(&n), "{n}");
        assert!(r < 6e-3 && r > 3e-3, "{r}");
        assert_eq!(
            radius_holding(&grid, &rest, &c, 2e-3, MAX_DENT_POINTS),
            2e-3
        );
    }
}

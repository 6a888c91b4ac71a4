//! Which one-sided contacts a static solve treats as pressed. Newton's method on a
//! penalty that switches on and off with the sign of a gap stalls (a contact about to
//! touch has no stiffness in the tangent, so the step overshoots and the line search
//! crawls); with the set frozen, the contacts in it act as two-sided springs and the
//! problem is smooth. The static solver converges on a frozen set, updates it from the
//! gaps, and repeats until it stops changing (an active-set method).

/// The pressed contacts, or none frozen (each contact pressed while its gap is negative).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ContactSet {
    frozen: bool,
    pressed: Vec<bool>,
}

impl ContactSet {
    /// Room for `n` contacts, none frozen.
    pub fn new(n: usize) -> Self {
        Self {
            frozen: false,
            pressed: vec![false; n],
        }
    }

    /// Whether contact i with gap `gap` (negative inside) pushes.
    #[inline]
    pub fn pressed(&self, i: usize, gap: f64) -> bool {
        if self.frozen {
            self.pressed[i]
        } else {
            gap < 0.0
        }
    }

    /// Whether contact i is held pressed by a frozen set (whatever its gap).
    #[inline]
    pub fn frozen_pressed(&self, i: usize) -> bool {
        self.frozen && self.pressed[i]
    }

    /// Freezes the set to the contacts with a negative gap; returns how many changed
    /// since the last frozen set (all pressed ones, the first time).
    pub fn freeze(&mut self, gaps: impl Iterator<Item = (usize, f64)>) -> usize {
        let mut changed = 0;
        for (i, gap) in gaps {
            let now = gap < 0.0;
            if std::mem::replace(&mut self.pressed[i], now) != now {
                changed += 1;
            }
        }
        self.frozen = true;
        changed
    }

    /// Back to the gaps' signs.
    pub fn thaw(&mut self) {
        self.frozen = false;
        self.pressed.iter_mut().for_each(|p| *p = false);
    }
}

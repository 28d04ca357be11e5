//! The stresses on the shear plane inside the sample, away from the box's walls: a
//! measurement every backend supplies ([`Backend::advance_sampling`](super::Backend::advance_sampling)).
//!
//! The box's walls take part in what the box's forces measure: the upper half's walls drag and
//! plough the grains next to them, and that share of the force grows with the walls' area
//! against the plane's (measured, cohesionless, sheared 10 mm: the box's force reads an
//! intercept of 1.59 / 0.93 / 0.65 kPa and φ 32.3 / 26.2 / 23.6° in boxes of 100 / 150 / 200 mm,
//! docs/shear.md). The soil's own strength is the stress the grains carry across the plane in
//! the middle of the box: here the contacts' forces in a window, a slab around the plane inset
//! from every wall, averaged over the slab's thickness (the Love-Weber mean stress σ_iz =
//! Σ f_i l_z / V of the part of each branch vector inside the slab, which is the mean over the
//! slab's horizontal planes of the force crossing them).

use repose_engine::world::{ContactForce, World};

/// The measurement window: `x`, `y` and `z` ranges, m (the slab is `z`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Window {
    pub x: [f64; 2],
    pub y: [f64; 2],
    pub z: [f64; 2],
}

/// Mean stresses across the window's horizontal planes, Pa: compression positive, and the
/// shear stress the lower grains resist the upper ones with along +x (positive when the upper
/// part is pushed along +x).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PlaneStress {
    pub normal_pa: f64,
    pub shear_pa: f64,
}

impl Window {
    fn volume(&self) -> f64 {
        (self.x[1] - self.x[0]) * (self.y[1] - self.y[0]) * (self.z[1] - self.z[0])
    }

    /// The stresses from `contacts`, each with the position of its particle i. A contact counts
    /// where the midpoint of its branch lies inside the window's `x` and `y` range, with the
    /// length of its branch's vertical extent inside the slab.
    pub fn stress(
        &self,
        contacts: impl IntoIterator<Item = (ContactForce, [f64; 3])>,
    ) -> PlaneStress {
        let mut sum = PlaneStress::default();
        for (c, xi) in contacts {
            self.add(&mut sum, &c, xi);
        }
        self.mean(sum)
    }

    /// The stresses from the contacts of `world`'s last force evaluation.
    pub fn stress_in(&self, world: &World) -> PlaneStress {
        let x = &world.particles().position;
        let mut sum = PlaneStress::default();
        world.for_each_contact(|c| {
            let xi = x[c.i];
            self.add(&mut sum, &c, [xi.x, xi.y, xi.z]);
        });
        self.mean(sum)
    }

    fn add(&self, sum: &mut PlaneStress, c: &ContactForce, xi: [f64; 3]) {
        let mid = [xi[0] + 0.5 * c.branch.x, xi[1] + 0.5 * c.branch.y];
        if mid[0] < self.x[0] || mid[0] >= self.x[1] || mid[1] < self.y[0] || mid[1] >= self.y[1] {
            return;
        }
        let zj = xi[2] + c.branch.z;
        let inside = (xi[2].max(zj).min(self.z[1]) - xi[2].min(zj).max(self.z[0])).max(0.0);
        if inside == 0.0 {
            return;
        }
        // The force on the upper grain of the pair, from the lower one.
        let on_upper = if c.branch.z >= 0.0 {
            c.force_on_j
        } else {
            -c.force_on_j
        };
        sum.normal_pa += on_upper.z * inside;
        sum.shear_pa -= on_upper.x * inside;
    }

    /// The stresses from the sum over the contacts of (the force on each pair's upper grain)
    /// × (the length of its branch's vertical extent inside the slab), N·m, as a GPU sums it:
    /// the same as [`Window::stress`] of those contacts.
    pub fn stress_of_sum(&self, sum: [f64; 3]) -> PlaneStress {
        self.mean(PlaneStress {
            normal_pa: sum[2],
            shear_pa: -sum[0],
        })
    }

    fn mean(&self, sum: PlaneStress) -> PlaneStress {
        let v = self.volume();
        PlaneStress {
            normal_pa: sum.normal_pa / v,
            shear_pa: sum.shear_pa / v,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use repose_engine::math::Vec3;

    fn contact(xi: [f64; 3], branch: [f64; 3], force_on_j: [f64; 3]) -> (ContactForce, [f64; 3]) {
        (
            ContactForce {
                i: 0,
                j: 1,
                force_on_j: Vec3::new(force_on_j[0], force_on_j[1], force_on_j[2]),
                branch: Vec3::new(branch[0], branch[1], branch[2]),
            },
            xi,
        )
    }

    /// A column of vertical contacts crossing the whole slab carries its force across every
    /// plane: the mean stress is the force over the window's area, whichever grain is i.
    #[test]
    fn vertical_contacts_across_the_slab_give_force_over_area() {
        let w = Window {
            x: [-0.5, 0.5],
            y: [-1.0, 1.0],
            z: [0.9, 1.1],
        };
        // The window's area is 2 m². Lower grain i pushes the upper grain j up by 3 N and back (−x) by 1 N: the lower
        // part resists a +x motion of the upper part.
        let up = contact([0.0, 0.0, 0.8], [0.0, 0.0, 0.4], [-1.0, 0.0, 3.0]);
        // The same contact seen from the upper grain: force on the lower grain j.
        let down = contact([0.2, 0.0, 1.2], [0.0, 0.0, -0.4], [1.0, 0.0, -3.0]);
        for c in [up, down] {
            let s = w.stress([c]);
            assert!((s.normal_pa - 3.0 / 2.0).abs() < 1e-12, "{s:?}");
            assert!((s.shear_pa - 1.0 / 2.0).abs() < 1e-12, "{s:?}");
        }
        // Outside the x range, below the slab, or half inside it.
        let outside = contact([0.6, 0.0, 0.8], [0.0, 0.0, 0.4], [-1.0, 0.0, 3.0]);
        let below = contact([0.0, 0.0, 0.3], [0.0, 0.0, 0.4], [-1.0, 0.0, 3.0]);
        assert_eq!(w.stress([outside, below]), PlaneStress::default());
        let half = contact([0.0, 0.0, 1.0], [0.0, 0.0, 0.4], [-1.0, 0.0, 3.0]);
        let s = w.stress([half]);
        assert!((s.normal_pa - 0.75).abs() < 1e-12 && (s.shear_pa - 0.25).abs() < 1e-12);
    }
}

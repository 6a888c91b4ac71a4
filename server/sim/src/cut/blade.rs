//! The virtual scalpel (paper §4.1, physics.md §4.1).
//!
//! The tool pose gives the tip P and, along the blade's back, a second point P' one blade
//! length away. The cutting edge runs from P toward P'. When the blade enters the tissue, the
//! blade plane is the plane through the edge perpendicular to the tissue surface at the entry
//! point: its normal is `n_b = normalize((P' − P) × ν_s)` with ν_s the surface normal there.
//! The blade's flat lies in the tool's local x–z plane, its back (the blade's width behind
//! the edge) toward local −x: what a blade pushed in point first slits (a stab incision).

use nalgebra::UnitQuaternion;
use serde::Serialize;

use crate::math::Vec3;
use crate::scene::ToolSpec;

/// A tool pose: where the blade tip is and how the tool is turned.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ToolPose {
    /// Blade tip (m).
    pub tip_m: Vec3,
    /// Orientation; the blade's edge runs along the tool's local +z axis from the tip, its
    /// back lies toward local −x.
    pub orientation: UnitQuaternion<f64>,
}

impl ToolPose {
    /// Whether the pose can be simulated: a finite tip and a finite orientation of unit
    /// length (to rounding).
    pub fn is_sound(&self) -> bool {
        let q = self.orientation.quaternion();
        self.tip_m.iter().all(|c| c.is_finite())
            && q.coords.iter().all(|c| c.is_finite())
            && (q.norm() - 1.0).abs() <= 1e-9
    }

    /// A pose with the edge pointing from the tip along `edge_direction` (any length).
    pub fn pointing(tip_m: Vec3, edge_direction: Vec3) -> Self {
        let orientation = UnitQuaternion::rotation_between(&Vec3::z(), &edge_direction)
            .unwrap_or_else(|| {
                UnitQuaternion::from_axis_angle(&Vec3::x_axis(), std::f64::consts::PI)
            });
        Self { tip_m, orientation }
    }

    /// A pose with the edge along `edge_direction` and the blade's sharp side toward
    /// `facing` (its back away from it; taken square to the edge). A `facing` along the
    /// edge leaves the turn of [`ToolPose::pointing`].
    pub fn facing(tip_m: Vec3, edge_direction: Vec3, facing: Vec3) -> Self {
        let Some(z) = edge_direction.try_normalize(1e-12) else {
            return Self::pointing(tip_m, edge_direction);
        };
        let Some(x) = (facing - z * facing.dot(&z)).try_normalize(1e-9) else {
            return Self::pointing(tip_m, edge_direction);
        };
        let frame = nalgebra::Matrix3::from_columns(&[x, z.cross(&x), z]);
        Self {
            tip_m,
            orientation: UnitQuaternion::from_rotation_matrix(
                &nalgebra::Rotation3::from_matrix_unchecked(frame),
            ),
        }
    }
}

/// The blade at one instant.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Blade {
    /// Tip P (m).
    pub tip: Vec3,
    /// Second point P' at the far end of the cutting edge (m).
    pub back: Vec3,
    /// Unit direction from P to P'.
    pub edge: Vec3,
    /// Unit direction across the blade's flat from its edge to its back (perpendicular to
    /// `edge`).
    pub toward_back: Vec3,
}

impl Blade {
    /// The blade for `pose` with the scene's tool geometry.
    pub fn at(pose: &ToolPose, tool: &ToolSpec) -> Self {
        let edge = pose.orientation * Vec3::z();
        Self {
            tip: pose.tip_m,
            back: pose.tip_m + edge * tool.blade_length_m,
            edge,
            toward_back: pose.orientation * -Vec3::x(),
        }
    }

    /// Normal of the blade plane given the surface normal at entry (paper §4.1): the plane
    /// contains the edge and the surface normal. When the edge is along the surface normal any
    /// plane through the edge will do; `None` only for a degenerate edge.
    pub fn plane_normal(&self, surface_normal: &Vec3) -> Option<Vec3> {
        let n = (self.back - self.tip).cross(surface_normal);
        n.try_normalize(1e-12).or_else(|| {
            // Edge parallel to the surface normal: any plane through the edge will do; pick
            // the one containing the world x axis (or y).
            let helper = if self.edge.x.abs() < 0.9 {
                Vec3::x()
            } else {
                Vec3::y()
            };
            self.edge.cross(&helper).try_normalize(1e-12)
        })
    }
}

/// One sample of the blade's path: where its edge crossed the surface and where its tip
/// was, both in rest space (m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PathSample {
    /// Entry point on the surface.
    pub surface: Vec3,
    /// Deepest tip position there.
    pub bottom: Vec3,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blade_edge_follows_the_pose() {
        let tool = ToolSpec::default();
        let pose = ToolPose::pointing(Vec3::new(0.0, 0.0, -0.01), Vec3::new(0.0, 0.0, 1.0));
        let b = Blade::at(&pose, &tool);
        assert!((b.back - Vec3::new(0.0, 0.0, -0.01 + tool.blade_length_m)).norm() < 1e-15);
        // A vertical blade entering a horizontal surface: the blade plane contains z.
        let n = b.plane_normal(&Vec3::new(0.0, 0.0, 1.0)).expect("a normal");
        assert!(n.dot(&Vec3::z()).abs() < 1e-12);
        let tilted = Blade::at(
            &ToolPose::pointing(Vec3::zeros(), Vec3::new(1.0, 0.0, 1.0)),
            &tool,
        );
        let n = tilted.plane_normal(&Vec3::z()).unwrap();
        assert!((n.norm() - 1.0).abs() < 1e-12 && n.dot(&tilted.edge).abs() < 1e-12);
        // The back is across the edge, behind it: a blade held upright to cut along +x
        // (the default pose) has its back toward −x.
        assert!(tilted.toward_back.dot(&tilted.edge).abs() < 1e-12);
        assert!((b.toward_back + Vec3::x()).norm() < 1e-12);
        // Held to cut along +y, leaning forward: the back is behind, square to the edge.
        let edge = Vec3::new(0.0, 1.0, 1.0);
        let turned = Blade::at(&ToolPose::facing(Vec3::zeros(), edge, Vec3::y()), &tool);
        assert!((turned.edge - edge.normalize()).norm() < 1e-12);
        let back = Vec3::new(0.0, -1.0, 1.0).normalize();
        assert!((turned.toward_back - back).norm() < 1e-12);
    }
}

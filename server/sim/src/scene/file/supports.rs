//! The scene file's `[loads]` and `[supports]` tables (docs/SCENES.md).

use serde::Deserialize;

use super::{Checker, Limit, MM, SceneError};
use crate::math::Vec3;
use crate::scene::SceneSpec;
use crate::scene::supports::{
    Attachment, DEFAULT_STIFFNESS_PA_PER_M, DEFAULT_TRAY_FRICTION, Region, Tray,
};

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawLoads {
    pub(super) gravity_m_s2: Option<[f64; 3]>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawSupports {
    pub(super) fixed: Option<Vec<RawRegion>>,
    pub(super) attachments: Option<Vec<RawAttachment>>,
    pub(super) tray: Option<RawTrayOrOff>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawRegion {
    box_mm: Option<RawBox>,
    box_fraction: Option<RawBox>,
    beyond_plane_mm: Option<RawPlane>,
    inside_cylinder_mm: Option<RawCylinder>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawCylinder {
    point: [f64; 3],
    axis: [f64; 3],
    radius: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawBox {
    min: [f64; 3],
    max: [f64; 3],
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawPlane {
    point: [f64; 3],
    normal: [f64; 3],
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawAttachment {
    region: RawRegion,
    stiffness_kpa_per_mm: Option<f64>,
}

/// `tray = false` (no tray, also for a scene that extends one with a tray) or a table.
#[derive(Debug, Deserialize)]
#[serde(untagged)]
pub(super) enum RawTrayOrOff {
    Off(bool),
    Tray(RawTray),
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawTray {
    normal: Option<[f64; 3]>,
    point_mm: Option<[f64; 3]>,
    friction: Option<f64>,
    stiffness_kpa_per_mm: Option<f64>,
}

/// Coordinates in mm beyond this are not a body's.
const MAX_COORDINATE_MM: f64 = 10_000.0;

/// Applies `[loads]` to `spec`.
pub(super) fn apply_loads(
    spec: &mut SceneSpec,
    raw: &RawLoads,
    check: &Checker<'_>,
) -> Result<(), SceneError> {
    if let Some(g) = raw.gravity_m_s2 {
        let limit = Limit::closed(-100.0, 100.0, "m/s²");
        for (a, v) in g.iter().enumerate() {
            check.check(&format!("loads.gravity_m_s2[{a}]"), *v, limit)?;
        }
        spec.loads.gravity = Vec3::from(g);
    }
    Ok(())
}

/// Applies `[supports]` to `spec`: each key given replaces that part of an extended scene's
/// supports (`fixed = []` removes its fixed regions, `tray = false` its tray).
pub(super) fn apply_supports(
    spec: &mut SceneSpec,
    raw: &RawSupports,
    check: &Checker<'_>,
) -> Result<(), SceneError> {
    if let Some(fixed) = &raw.fixed {
        spec.supports.fixed = fixed
            .iter()
            .enumerate()
            .map(|(k, r)| region(r, &format!("supports.fixed[{k}]"), check))
            .collect::<Result<_, _>>()?;
    }
    if let Some(attachments) = &raw.attachments {
        spec.supports.attachments = attachments
            .iter()
            .enumerate()
            .map(|(k, a)| {
                let key = format!("supports.attachments[{k}]");
                Ok(Attachment {
                    region: region(&a.region, &format!("{key}.region"), check)?,
                    stiffness_pa_per_m: stiffness(
                        a.stiffness_kpa_per_mm,
                        &format!("{key}.stiffness_kpa_per_mm"),
                        check,
                    )?,
                })
            })
            .collect::<Result<_, _>>()?;
    }
    match &raw.tray {
        None => {}
        Some(RawTrayOrOff::Off(false)) => spec.supports.tray = None,
        Some(RawTrayOrOff::Off(true)) => {
            return Err(check.fail(
                "supports.tray",
                "give the tray as a table ({ normal = [0, 0, 1] } for a level one), or false",
            ));
        }
        Some(RawTrayOrOff::Tray(t)) => spec.supports.tray = Some(tray(t, check)?),
    }
    Ok(())
}

/// A stiffness per area in kPa/mm (default 1), in Pa/m.
fn stiffness(value: Option<f64>, key: &str, check: &Checker<'_>) -> Result<f64, SceneError> {
    match value {
        None => Ok(DEFAULT_STIFFNESS_PA_PER_M),
        Some(v) => Ok(check.check(key, v, Limit::positive(1000.0, "kPa/mm"))? * 1e6),
    }
}

fn tray(t: &RawTray, check: &Checker<'_>) -> Result<Tray, SceneError> {
    let normal = unit(
        t.normal.unwrap_or([0.0, 0.0, 1.0]),
        "supports.tray.normal",
        check,
    )?;
    let point = t
        .point_mm
        .map(|p| coordinates(p, "supports.tray.point_mm", check))
        .transpose()?;
    let friction = match t.friction {
        None => DEFAULT_TRAY_FRICTION,
        Some(f) => check.check("supports.tray.friction", f, Limit::closed(0.0, 2.0, ""))?,
    };
    Ok(Tray {
        normal,
        point,
        friction,
        stiffness_pa_per_m: stiffness(
            t.stiffness_kpa_per_mm,
            "supports.tray.stiffness_kpa_per_mm",
            check,
        )?,
    })
}

/// A region: exactly one of `box_mm`, `box_fraction`, `beyond_plane_mm` and
/// `inside_cylinder_mm`.
fn region(r: &RawRegion, key: &str, check: &Checker<'_>) -> Result<Region, SceneError> {
    match (
        &r.box_mm,
        &r.box_fraction,
        &r.beyond_plane_mm,
        &r.inside_cylinder_mm,
    ) {
        (Some(b), None, None, None) => {
            ordered(b.min, b.max, &format!("{key}.box_mm"), check)?;
            Ok(Region::Box {
                min: coordinates(b.min, &format!("{key}.box_mm.min"), check)?,
                max: coordinates(b.max, &format!("{key}.box_mm.max"), check)?,
            })
        }
        (None, Some(b), None, None) => {
            let limit = Limit::closed(0.0, 1.0, "");
            for (a, (lo, hi)) in b.min.iter().zip(&b.max).enumerate() {
                check.check(&format!("{key}.box_fraction.min[{a}]"), *lo, limit)?;
                check.check(&format!("{key}.box_fraction.max[{a}]"), *hi, limit)?;
            }
            ordered(b.min, b.max, &format!("{key}.box_fraction"), check)?;
            Ok(Region::BoxFraction {
                min: b.min,
                max: b.max,
            })
        }
        (None, None, Some(p), None) => Ok(Region::BeyondPlane {
            point: coordinates(p.point, &format!("{key}.beyond_plane_mm.point"), check)?,
            normal: unit(p.normal, &format!("{key}.beyond_plane_mm.normal"), check)?,
        }),
        (None, None, None, Some(c)) => {
            let limit = Limit::positive(MAX_COORDINATE_MM, "mm");
            let radius =
                check.check(&format!("{key}.inside_cylinder_mm.radius"), c.radius, limit)?;
            Ok(Region::InsideCylinder {
                point: coordinates(c.point, &format!("{key}.inside_cylinder_mm.point"), check)?,
                axis: unit(c.axis, &format!("{key}.inside_cylinder_mm.axis"), check)?,
                radius: radius * MM,
            })
        }
        _ => Err(check.fail(
            key,
            "give exactly one of box_mm = { min, max }, box_fraction = { min, max }, \
             beyond_plane_mm = { point, normal } and inside_cylinder_mm = { point, axis, radius }",
        )),
    }
}

/// A point in mm, range-checked, in m.
fn coordinates(p: [f64; 3], key: &str, check: &Checker<'_>) -> Result<[f64; 3], SceneError> {
    let limit = Limit::closed(-MAX_COORDINATE_MM, MAX_COORDINATE_MM, "mm");
    let mut out = [0.0; 3];
    for a in 0..3 {
        out[a] = check.check(&format!("{key}[{a}]"), p[a], limit)? * MM;
    }
    Ok(out)
}

/// A direction, normalised; refused when zero or not finite.
fn unit(v: [f64; 3], key: &str, check: &Checker<'_>) -> Result<[f64; 3], SceneError> {
    let n = Vec3::from(v);
    let length = n.norm();
    if !length.is_finite() || length < 1e-9 {
        return Err(check.fail(key, format!("{v:?} is not a direction")));
    }
    Ok((n / length).into())
}

fn ordered(min: [f64; 3], max: [f64; 3], key: &str, check: &Checker<'_>) -> Result<(), SceneError> {
    match (0..3).find(|&a| min[a] > max[a]) {
        Some(a) => Err(check.fail(
            key,
            format!("min[{a}] = {} is above max[{a}] = {}", min[a], max[a]),
        )),
        None => Ok(()),
    }
}

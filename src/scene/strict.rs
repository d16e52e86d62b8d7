//! Strict readers for the scene's `[x, y, z]` keys: exactly three numbers, each finite once
//! converted to the type the renderer uses (serde alone drops a fourth number, and `1e39` becomes
//! an f32 infinity).

use serde::{Deserialize, Deserializer, de::Error};

fn three<'de, D: Deserializer<'de>>(d: D) -> Result<[f64; 3], D::Error> {
    let v = Vec::<f64>::deserialize(d)?;
    <[f64; 3]>::try_from(v.as_slice())
        .map_err(|_| D::Error::custom(format!("expected 3 numbers, got {}", v.len())))
}

fn in_f32<E: Error>(v: [f64; 3]) -> Result<[f32; 3], E> {
    let f = v.map(|c| c as f32);
    if f.iter().all(|c| c.is_finite()) {
        Ok(f)
    } else {
        Err(E::custom(format!("{v:?} is not finite as a 32-bit float")))
    }
}

/// `[f64; 3]` that is also finite in f32 (cameras and placements reach the GPU as f32).
pub fn f64x3<'de, D: Deserializer<'de>>(d: D) -> Result<[f64; 3], D::Error> {
    let v = three(d)?;
    in_f32::<D::Error>(v)?;
    Ok(v)
}

pub fn opt_f64x3<'de, D: Deserializer<'de>>(d: D) -> Result<Option<[f64; 3]>, D::Error> {
    f64x3(d).map(Some)
}

pub fn opt_f32x3<'de, D: Deserializer<'de>>(d: D) -> Result<Option<[f32; 3]>, D::Error> {
    in_f32(three(d)?).map(Some)
}

/// `range = [a, b]`: two numbers, finite as 32-bit floats, `a < b`.
pub fn opt_range<'de, D: Deserializer<'de>>(d: D) -> Result<Option<[f32; 2]>, D::Error> {
    let v = Vec::<f64>::deserialize(d)?;
    let [a, b] = <[f64; 2]>::try_from(v.as_slice())
        .map_err(|_| D::Error::custom(format!("expected 2 numbers, got {}", v.len())))?;
    let (fa, fb) = (a as f32, b as f32);
    if !(fa.is_finite() && fb.is_finite()) {
        return Err(D::Error::custom(format!(
            "[{a}, {b}] is not finite as 32-bit floats"
        )));
    }
    if fa >= fb {
        return Err(D::Error::custom(format!(
            "[{a}, {b}] is empty: the first value must be below the second"
        )));
    }
    Ok(Some([fa, fb]))
}

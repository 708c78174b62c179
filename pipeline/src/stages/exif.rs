//! A photo's focal length from its EXIF, in the photo's pixels: the 35 mm-equivalent focal
//! length (`FocalLengthIn35mmFilm`, over the 35 mm frame's 43.27 mm diagonal), else the focal
//! length in millimetres times the sensor's pixels per millimetre (`FocalLength` ×
//! `FocalPlaneXResolution`, scaled by the photo's width over the sensor image's
//! `PixelXDimension` when the photo was resized). A value implying a field of view outside
//! 10–150° is not believed; nor a sensor focal length whose resolution implies a sensor
//! narrower than 4 mm, as a resizer that rewrote `PixelXDimension` but kept the sensor's
//! resolution leaves it (no camera that writes that tag has one so small).

use exif::{In, Tag, Value};

/// Diagonal of the 35 mm film frame (36 × 24 mm), millimetres.
const FRAME_DIAGONAL_MM: f64 = 43.266_615;

/// Narrowest and widest believable diagonal field of view, degrees.
const FOV_RANGE: std::ops::RangeInclusive<f64> = 10.0..=150.0;

/// Narrowest believable sensor, millimetres (phones' 1/3.2" sensors are 4.5 mm wide).
const MIN_SENSOR_MM: f64 = 4.0;

/// The focal length, in pixels, of a photo `width`×`height` (as stored, before any EXIF
/// turn: the sensor's axes) whose raw EXIF (TIFF) block is `raw`; `None` when it says none
/// that can be believed.
pub fn focal_px(raw: Vec<u8>, width: u32, height: u32) -> Option<f32> {
    let exif = exif::Reader::new().read_raw(raw).ok()?;
    let field = |tag: Tag| exif.get_field(tag, In::PRIMARY).map(|f| &f.value);
    let number = |tag: Tag| -> Option<f64> {
        match field(tag)? {
            Value::Rational(v) => v.first().map(|r| r.to_f64()),
            Value::SRational(v) => v.first().map(|r| r.to_f64()),
            v => v.get_uint(0).map(f64::from),
        }
    };
    let (w, h) = (f64::from(width), f64::from(height));
    let diagonal = w.hypot(h);
    let from_35mm = number(Tag::FocalLengthIn35mmFilm)
        .filter(|f| *f > 0.0)
        .map(|f35| f35 / FRAME_DIAGONAL_MM * diagonal);
    let from_sensor = || {
        let mm = number(Tag::FocalLength).filter(|f| *f > 0.0)?;
        let per_unit = number(Tag::FocalPlaneXResolution).filter(|r| *r > 0.0)?;
        let unit_mm = match field(Tag::FocalPlaneResolutionUnit).and_then(|v| v.get_uint(0)) {
            None | Some(2) => 25.4,
            Some(3) => 10.0,
            Some(4) => 1.0,
            Some(_) => return None,
        };
        let per_mm = per_unit / unit_mm;
        let sensor_px = number(Tag::PixelXDimension).filter(|p| *p > 0.0).unwrap_or(w);
        (sensor_px / per_mm >= MIN_SENSOR_MM).then_some(mm * per_mm * w / sensor_px)
    };
    let focal = from_35mm.or_else(from_sensor)?;
    let fov = 2.0 * (0.5 * diagonal / focal).atan().to_degrees();
    (focal.is_finite() && FOV_RANGE.contains(&fov)).then_some(focal as f32)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use exif::{Field, Rational};

    /// A raw EXIF block with `fields` (primary image).
    pub(crate) fn raw_exif(fields: &[Field]) -> Vec<u8> {
        let mut writer = exif::experimental::Writer::new();
        for f in fields {
            writer.push_field(f);
        }
        let mut out = std::io::Cursor::new(Vec::new());
        writer.write(&mut out, false).unwrap();
        out.into_inner()
    }

    pub(crate) fn field(tag: Tag, value: Value) -> Field {
        Field { tag, ifd_num: In::PRIMARY, value }
    }

    #[test]
    fn reads_the_35mm_equivalent_then_the_sensor_focal_length() {
        // A 26 mm-equivalent phone lens on a 4000 × 3000 photo: 26 / 43.27 × 5000 px.
        let raw = raw_exif(&[field(Tag::FocalLengthIn35mmFilm, Value::Short(vec![26]))]);
        let f = focal_px(raw, 4000, 3000).unwrap();
        assert!((f - 3004.6).abs() < 1.0, "{f}");
        // 4.25 mm on a 5 mm sensor of 800 pixels per mm (unit 4 = mm), the photo at half the
        // sensor's 4000 px width.
        let sensor = |px_per_mm: u32, width: u32| {
            raw_exif(&[
                field(Tag::FocalLength, Value::Rational(vec![Rational { num: 425, denom: 100 }])),
                field(
                    Tag::FocalPlaneXResolution,
                    Value::Rational(vec![Rational::from((px_per_mm, 1))]),
                ),
                field(Tag::FocalPlaneResolutionUnit, Value::Short(vec![4])),
                field(Tag::PixelXDimension, Value::Long(vec![width])),
            ])
        };
        let f = focal_px(sensor(800, 4000), 2000, 1500).unwrap();
        assert!((f - 1700.0).abs() < 0.5, "{f}");
        // The same photo resized to 718 px by a tool that rewrote the pixel dimension and kept
        // the sensor's resolution (opencv_contrib's sfm street photos): a 0.9 mm sensor.
        assert_eq!(focal_px(sensor(800, 718), 718, 480), None);
        // A focal length that would mean a 2° field of view is not believed; nor no EXIF.
        let raw = raw_exif(&[field(Tag::FocalLengthIn35mmFilm, Value::Short(vec![1200]))]);
        assert_eq!(focal_px(raw, 4000, 3000), None);
        assert_eq!(focal_px(b"not exif".to_vec(), 4000, 3000), None);
    }
}

//! Photos as a phone writes them: JPEG with EXIF fields (orientation, focal length).

use std::path::Path;

use image::{ImageEncoder, RgbImage};

/// Writes `rgb` to `path` as a JPEG whose EXIF holds `fields` (primary image).
pub fn save_jpeg_with_exif(rgb: &RgbImage, fields: &[(exif::Tag, exif::Value)], path: &Path) {
    let fields: Vec<exif::Field> = fields
        .iter()
        .map(|(tag, value)| exif::Field {
            tag: *tag,
            ifd_num: exif::In::PRIMARY,
            value: value.clone(),
        })
        .collect();
    let mut writer = exif::experimental::Writer::new();
    fields.iter().for_each(|f| writer.push_field(f));
    let mut raw = std::io::Cursor::new(Vec::new());
    writer.write(&mut raw, false).unwrap();
    let mut file = std::fs::File::create(path).unwrap();
    let mut jpeg = image::codecs::jpeg::JpegEncoder::new_with_quality(&mut file, 95);
    jpeg.set_exif_metadata(raw.into_inner()).unwrap();
    let (w, h) = rgb.dimensions();
    jpeg.write_image(rgb.as_raw(), w, h, image::ExtendedColorType::Rgb8).unwrap();
}

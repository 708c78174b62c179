//! Decode stage: photo bytes (JPEG, PNG, WebP) → RGB with EXIF orientation applied → fitted
//! into the model's input: one size for the request ([`input_size`]), the photos' own aspect
//! where the network takes it (its long side at the model's resolution, the short side
//! rounded up to the network's size multiple), else the square, the rest of each photo's box
//! grey bars; for registration, a copy of a photo larger than
//! that input at up to `RegisterParams::photo_size` pixels; and the copy at the size of the
//! masks, which guides their upsampling (all resized by `fast_image_resize`). The header is
//! read first: other formats (HEIC, TIFF, …) and oversized, empty or strip-shaped images are
//! refused before any pixel is decoded, so memory stays bounded whatever is sent.

use std::io::Cursor;

use image::{DynamicImage, ImageDecoder, ImageReader, RgbImage};
use inssplat_proto::Intrinsics;
use rayon::prelude::*;

use super::exif;

/// Largest accepted image, in pixels (a 40-megapixel photo).
pub const MAX_PIXELS: u64 = 40_000_000;

/// Largest accepted ratio of a photo's long side to its short side: a longer strip keeps too
/// few pixels across in the model's square input to reconstruct from.
pub const MAX_ASPECT: u32 = 16;

/// Grey used for letterbox padding (mean of [0, 1]).
const PAD: f32 = 0.5;

#[derive(Debug, thiserror::Error)]
pub enum DecodeError {
    #[error("{name}: empty file")]
    Empty { name: String },
    #[error("{name}: not a supported image (JPEG, PNG or WebP): {message}")]
    Format { name: String, message: String },
    /// An image in a format the service does not read (HEIC from a phone, TIFF, GIF, …).
    #[error(
        "{name}: {format} images are not supported; send JPEG, PNG or WebP (a phone's HEIC photo converts with e.g. `heif-convert` or its share-as-JPEG setting)"
    )]
    Unsupported { name: String, format: String },
    #[error(
        "{name}: image is {width}×{height}; images must be non-empty and at most {MAX_PIXELS} pixels"
    )]
    Size { name: String, width: u32, height: u32 },
    #[error(
        "{name}: image is {width}×{height}, a strip: its long side may be at most {MAX_ASPECT} times its short side"
    )]
    Strip { name: String, width: u32, height: u32 },
    #[error("{name}: corrupt image data: {message}")]
    Corrupt { name: String, message: String },
}

/// How an input photo maps into the model's input.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Letterbox {
    /// Original size after EXIF orientation.
    pub width: u32,
    pub height: u32,
    /// The model's input, width and height in pixels.
    pub input: [u32; 2],
    /// Model pixels per original pixel.
    pub scale: f32,
    /// Offset of the photo inside the input, in model pixels.
    pub pad_x: f32,
    pub pad_y: f32,
}

impl Letterbox {
    /// The photo's pixels inside the input, `[x0, y0, x1, y1)` in model pixels.
    pub fn photo_rect(&self) -> [u32; 4] {
        let (x1, y1) = (
            self.pad_x + self.width as f32 * self.scale,
            self.pad_y + self.height as f32 * self.scale,
        );
        [self.pad_x.ceil() as u32, self.pad_y.ceil() as u32, x1.floor() as u32, y1.floor() as u32]
    }

    /// Intrinsics in the original photo for intrinsics predicted at the model resolution.
    pub fn to_original(&self, k: &Intrinsics) -> Intrinsics {
        Intrinsics {
            fx: k.fx / self.scale,
            fy: k.fy / self.scale,
            cx: (k.cx - self.pad_x) / self.scale,
            cy: (k.cy - self.pad_y) / self.scale,
            width: self.width,
            height: self.height,
        }
    }
}

/// A decoded photo ready for the network.
#[derive(Debug, Clone)]
pub struct ModelImage {
    /// Planar `[3][H][W]` in [0, 1], `[W, H]` the letterbox's `input`.
    pub planar: Vec<f32>,
    pub letterbox: Letterbox,
    /// The photo at a finer scale than the model's input, for registration to find keypoints
    /// in (`None` when the photo is no larger than the input or none was asked).
    pub detail: Option<Detail>,
    /// The focal length its EXIF gives, in the photo's pixels ([`super::exif`]).
    pub exif_focal: Option<f32>,
    /// The photo at the masks' size ([`Sizes::mask`]); `None` when none was asked.
    pub guide: Option<RgbImage>,
    /// The photo for the object detector ([`Sizes::detect`]); `None` when none was asked.
    pub detect: Option<RgbImage>,
}

/// The sizes a photo is decoded to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Sizes {
    /// Long side of the model's input (the side of the square it was trained at).
    pub res: u32,
    /// What the input's sides may be multiples of, no longer than `res` (the network's size
    /// multiple); `None`: the square only.
    pub multiple: Option<u32>,
    /// Long side of the copy registration finds keypoints in (see [`ModelImage::detail`]).
    pub detail: u32,
    /// Long side of the masks at the photo's resolution, no larger than the photo's own
    /// (0: none).
    pub mask: u32,
    /// Long side of the copy the object detector reads, no larger than the photo's own (0:
    /// none).
    pub detect: u32,
}

/// A copy of a photo and its pixels per original pixel.
#[derive(Debug, Clone)]
pub struct Detail {
    pub rgb: RgbImage,
    pub scale: f32,
}

impl ModelImage {
    /// The detail's pixels per model pixel, and the model pixel of its top-left corner.
    pub fn detail_in_model(&self) -> Option<(&RgbImage, f32, [f32; 2])> {
        let lb = &self.letterbox;
        self.detail.as_ref().map(|d| (&d.rgb, d.scale / lb.scale, [lb.pad_x, lb.pad_y]))
    }
}

/// Decodes each named photo (in parallel) and fits them all into one input size
/// ([`input_size`]); keeps the copies `sizes` asks for. The first photo that cannot be read is
/// the error.
pub fn decode_all<'a>(
    photos: impl IntoParallelIterator<Item = (&'a str, &'a [u8])>,
    sizes: Sizes,
) -> Result<Vec<ModelImage>, DecodeError> {
    let decoded: Vec<(RgbImage, Option<f32>)> = photos
        .into_par_iter()
        .map(|(name, bytes)| decode_rgb(name, bytes))
        .collect::<Result<_, _>>()?;
    let input = input_size(decoded.iter().map(|(rgb, _)| rgb.dimensions()), sizes);
    Ok(decoded
        .into_par_iter()
        .map(|(rgb, exif_focal)| {
            let mut image = letterbox(&rgb, input);
            image.guide = (sizes.mask > 0).then(|| at_most(&rgb, sizes.mask));
            image.detect = (sizes.detect > 0).then(|| at_most(&rgb, sizes.detect));
            image.detail = detail_copy(rgb, sizes.res, sizes.detail);
            image.exif_focal = exif_focal;
            image
        })
        .collect())
}

/// The model's input, `[width, height]`, for photos of `dims` (after EXIF orientation): the
/// smallest box of multiples of `sizes.multiple`, its long side `sizes.res`, that holds each
/// photo scaled to `res` on its long side; so photos of one aspect fill it but for a bar under
/// one multiple, and landscape and portrait photos together get the square. The square
/// without a multiple.
pub fn input_size(dims: impl IntoIterator<Item = (u32, u32)>, sizes: Sizes) -> [u32; 2] {
    let res = sizes.res;
    let Some(m) = sizes.multiple else { return [res, res] };
    let fitted = |(w, h): (u32, u32)| {
        let s = res as f32 / w.max(h) as f32;
        [(w as f32 * s).round() as u32, (h as f32 * s).round() as u32]
    };
    let [w, h] = dims.into_iter().map(fitted).fold([0, 0], |[a, b], [w, h]| [a.max(w), b.max(h)]);
    [w, h].map(|side| side.div_ceil(m).max(1).saturating_mul(m).min(res))
}

/// `rgb` with its long side scaled down to `long` when longer.
pub(crate) fn at_most(rgb: &RgbImage, long: u32) -> RgbImage {
    let (w, h) = rgb.dimensions();
    if w.max(h) <= long {
        return rgb.clone();
    }
    let s = long as f32 / w.max(h) as f32;
    resize(rgb, ((w as f32 * s).round() as u32).max(1), ((h as f32 * s).round() as u32).max(1))
}

/// Decodes to RGB with EXIF orientation applied; with the focal length in pixels that its
/// EXIF gives, if any.
pub fn decode_rgb(name: &str, bytes: &[u8]) -> Result<(RgbImage, Option<f32>), DecodeError> {
    if bytes.is_empty() {
        return Err(DecodeError::Empty { name: name.into() });
    }
    let format_err = |e: &dyn std::fmt::Display| DecodeError::Format {
        name: name.into(),
        message: e.to_string(),
    };
    let unsupported =
        |format: &str| DecodeError::Unsupported { name: name.into(), format: format.to_string() };
    if let Some(format) = heif_brand(bytes) {
        return Err(unsupported(format));
    }
    let reader =
        ImageReader::new(Cursor::new(bytes)).with_guessed_format().map_err(|e| format_err(&e))?;
    match reader.format() {
        None => return Err(format_err(&"unrecognized file signature")),
        Some(image::ImageFormat::Jpeg | image::ImageFormat::Png | image::ImageFormat::WebP) => {}
        Some(other) => return Err(unsupported(&format!("{other:?}").to_uppercase())),
    }
    let mut decoder = reader.into_decoder().map_err(|e| format_err(&e))?;
    let (width, height) = decoder.dimensions();
    if width == 0 || height == 0 || u64::from(width) * u64::from(height) > MAX_PIXELS {
        return Err(DecodeError::Size { name: name.into(), width, height });
    }
    if width.max(height) > MAX_ASPECT * width.min(height) {
        return Err(DecodeError::Strip { name: name.into(), width, height });
    }
    let orientation = decoder.orientation().unwrap_or(image::metadata::Orientation::NoTransforms);
    let focal =
        decoder.exif_metadata().ok().flatten().and_then(|raw| exif::focal_px(raw, width, height));
    let mut img = DynamicImage::from_decoder(decoder)
        .map_err(|e| DecodeError::Corrupt { name: name.into(), message: e.to_string() })?;
    img.apply_orientation(orientation);
    Ok((img.into_rgb8(), focal))
}

/// The format an ISO base media file (`ftyp` box) says it holds, when it is one of the HEIF
/// family that phones save (HEIC, HEIF) or AVIF; `None` for anything else.
fn heif_brand(bytes: &[u8]) -> Option<&'static str> {
    if bytes.get(4..8) != Some(b"ftyp") {
        return None;
    }
    match bytes.get(8..12)? {
        b"heic" | b"heix" | b"hevc" | b"hevx" | b"heim" | b"heis" | b"hevm" | b"hevs" => {
            Some("HEIC")
        }
        b"mif1" | b"msf1" => Some("HEIF"),
        b"avif" | b"avis" => Some("AVIF"),
        _ => None,
    }
}

/// A photo as an output folder keeps it, for other tools to open beside `transforms.json`:
/// its own bytes when it is a JPEG or PNG that needs no EXIF turning (nothing re-encoded), else
/// its pixels as `decode_rgb` reads them (turned upright) in a PNG. Returns the bytes and their
/// file extension.
pub fn portable_photo(name: &str, bytes: &[u8]) -> Result<(Vec<u8>, &'static str), DecodeError> {
    let reader = ImageReader::new(Cursor::new(bytes)).with_guessed_format();
    let format = reader.as_ref().ok().and_then(|r| r.format());
    let upright = || -> Option<bool> {
        let mut decoder = reader.ok()?.into_decoder().ok()?;
        Some(matches!(decoder.orientation().ok()?, image::metadata::Orientation::NoTransforms))
    };
    let ext = match format {
        Some(image::ImageFormat::Jpeg) => "jpg",
        Some(image::ImageFormat::Png) => "png",
        _ => "",
    };
    if !ext.is_empty() && upright() == Some(true) {
        return Ok((bytes.to_vec(), ext));
    }
    let (rgb, _) = decode_rgb(name, bytes)?;
    let mut png = Cursor::new(Vec::new());
    rgb.write_to(&mut png, image::ImageFormat::Png)
        .map_err(|e| DecodeError::Corrupt { name: name.into(), message: e.to_string() })?;
    Ok((png.into_inner(), "png"))
}

/// `rgb`, its long side scaled down to `detail` if longer; `None` when it is no longer than
/// `res` or `detail` is no larger than `res`.
fn detail_copy(rgb: RgbImage, res: u32, detail: u32) -> Option<Detail> {
    let (w, h) = rgb.dimensions();
    let long = w.max(h);
    if detail <= res || long <= res {
        return None;
    }
    if long <= detail {
        return Some(Detail { rgb, scale: 1.0 });
    }
    let s = detail as f32 / long as f32;
    let (dw, dh) = (((w as f32 * s).round() as u32).max(1), ((h as f32 * s).round() as u32).max(1));
    Some(Detail { rgb: resize(&rgb, dw, dh), scale: dw as f32 / w as f32 })
}

/// `rgb` resized to `w`×`h` by a bilinear convolution whose support widens with the
/// reduction (the triangle filter), with the `fast_image_resize` crate's SIMD kernels: image's
/// own resize of 12 MP photos took a fifth of a request's time.
fn resize(rgb: &RgbImage, w: u32, h: u32) -> RgbImage {
    use fast_image_resize::images::{Image, ImageRef};
    use fast_image_resize::{FilterType, PixelType, ResizeAlg, ResizeOptions, Resizer};
    let src = ImageRef::new(rgb.width(), rgb.height(), rgb.as_raw(), PixelType::U8x3)
        .expect("an RGB image's buffer");
    let mut dst = Image::new(w, h, PixelType::U8x3);
    let options = ResizeOptions::new().resize_alg(ResizeAlg::Convolution(FilterType::Bilinear));
    Resizer::new().resize(&src, &mut dst, &options).expect("RGB on both sides");
    RgbImage::from_raw(w, h, dst.into_vec()).expect("w × h RGB pixels")
}

/// Scales `rgb` to fit `input` (`[width, height]`) keeping its aspect ratio, centred, and pads
/// the rest with grey.
fn letterbox(rgb: &RgbImage, input: [u32; 2]) -> ModelImage {
    let (w, h) = rgb.dimensions();
    let [iw, ih] = input;
    let scale = (iw as f32 / w as f32).min(ih as f32 / h as f32);
    let (nw, nh) = (
        ((w as f32 * scale).round() as u32).clamp(1, iw),
        ((h as f32 * scale).round() as u32).clamp(1, ih),
    );
    let resized = if (nw, nh) == (w, h) { rgb.clone() } else { resize(rgb, nw, nh) };
    let (ox, oy) = ((iw - nw) / 2, (ih - nh) / 2);
    let n = (iw * ih) as usize;
    let mut planar = vec![PAD; 3 * n];
    for (x, y, p) in resized.enumerate_pixels() {
        let i = ((y + oy) * iw + (x + ox)) as usize;
        for c in 0..3 {
            planar[c * n + i] = f32::from(p[c]) / 255.0;
        }
    }
    ModelImage {
        planar,
        letterbox: Letterbox {
            width: w,
            height: h,
            input,
            scale: nw as f32 / w as f32,
            pad_x: ox as f32,
            pad_y: oy as f32,
        },
        detail: None,
        exif_focal: None,
        guide: None,
        detect: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sizes(res: u32, detail: u32) -> Sizes {
        Sizes { res, multiple: None, detail, mask: 0, detect: 0 }
    }

    /// One photo decoded as the stage decodes a request.
    fn decode(name: &str, bytes: &[u8], sizes: Sizes) -> Result<ModelImage, DecodeError> {
        Ok(decode_all([(name, bytes)], sizes)?.remove(0))
    }

    fn png(w: u32, h: u32) -> Vec<u8> {
        let img = RgbImage::from_fn(w, h, |x, y| image::Rgb([(x * 10) as u8, (y * 10) as u8, 200]));
        let mut out = Cursor::new(Vec::new());
        img.write_to(&mut out, image::ImageFormat::Png).unwrap();
        out.into_inner()
    }

    #[test]
    fn letterboxes_wide_image_into_the_middle() {
        let m = decode("a.png", &png(20, 10), sizes(10, 0)).unwrap();
        assert_eq!(
            m.letterbox,
            Letterbox {
                width: 20,
                height: 10,
                input: [10, 10],
                scale: 0.5,
                pad_x: 0.0,
                pad_y: 2.0
            }
        );
        let n = 100;
        assert_eq!(m.planar[0], PAD, "top rows are padding");
        assert!(
            (m.planar[2 * n + 2 * 10 + 3] - 200.0 / 255.0).abs() < 1e-6,
            "blue channel of the photo"
        );
        let k = Intrinsics { fx: 10.0, fy: 10.0, cx: 5.0, cy: 5.0, width: 10, height: 10 };
        let back = m.letterbox.to_original(&k);
        assert_eq!((back.fx, back.cx, back.cy, back.width, back.height), (20.0, 10.0, 6.0, 20, 10));
    }

    /// With a size multiple the input takes the photos' aspect: 4:3 landscape photos a box
    /// 128 × 96, a 3:2 one rounded up to the multiple (a bar of 5 rows each side), portrait
    /// photos the transposed box, the two together the square; no multiple, the square.
    #[test]
    fn the_input_takes_the_photos_aspect_rounded_to_the_multiple() {
        let aspect = Sizes { res: 128, multiple: Some(32), detail: 0, mask: 0, detect: 0 };
        assert_eq!(input_size([(640, 480), (4000, 3000)], aspect), [128, 96]);
        assert_eq!(input_size([(480, 640)], aspect), [96, 128]);
        assert_eq!(input_size([(640, 480), (480, 640)], aspect), [128, 128]);
        assert_eq!(input_size([(1000, 50)], aspect), [128, 32], "a strip keeps one multiple");
        assert_eq!(input_size([(640, 480)], Sizes { multiple: None, ..aspect }), [128, 128]);
        let wide = decode("w.png", &png(300, 200), aspect).unwrap();
        let lb = wide.letterbox;
        assert_eq!(
            (lb.input, lb.pad_x, lb.pad_y, lb.photo_rect()),
            ([128, 96], 0.0, 5.0, [0, 5, 128, 90])
        );
        assert_eq!(wide.planar.len(), 3 * 128 * 96);
        let blue = |row: usize| wide.planar[2 * 128 * 96 + row * 128];
        assert_eq!((blue(4), blue(5), blue(90)), (PAD, 200.0 / 255.0, PAD), "bars about the photo");
    }

    #[test]
    fn keeps_a_detail_copy_only_of_photos_larger_than_the_input() {
        // 40×20 into 10×10 (scale 1/4, 5 rows of padding split 2 above), the detail at 16 wide.
        let m = decode("a.png", &png(40, 20), sizes(10, 16)).unwrap();
        let (copy, per_view, origin) = m.detail_in_model().expect("a detail");
        assert_eq!((copy.dimensions(), per_view, origin), ((16, 8), 1.6, [0.0, 2.0]));
        // Pixel (5, 0) of the 40×20 is (50, 0, 200).
        let exact = decode("a.png", &png(40, 20), sizes(10, 40)).unwrap().detail.unwrap();
        assert_eq!(
            (exact.scale, exact.rgb.get_pixel(5, 0).0),
            (1.0, [50, 0, 200]),
            "no larger than asked: kept as it is"
        );
        assert!(
            decode("a.png", &png(10, 5), sizes(10, 16)).unwrap().detail.is_none(),
            "no larger than the input"
        );
        assert!(
            decode("a.png", &png(40, 20), sizes(10, 10)).unwrap().detail.is_none(),
            "no detail asked"
        );
    }

    #[test]
    fn refuses_empty_garbage_and_huge_inputs_by_name() {
        assert!(matches!(decode("e.png", b"", sizes(8, 0)), Err(DecodeError::Empty { .. })));
        let err = decode("junk.jpg", b"this is not an image", sizes(8, 0)).unwrap_err();
        assert!(
            matches!(err, DecodeError::Format { .. }) && err.to_string().starts_with("junk.jpg"),
            "{err}"
        );
        // A valid PNG header claiming 20000×20000: refused from the header, before decoding.
        let mut huge = png(1, 1);
        huge[16..20].copy_from_slice(&20000u32.to_be_bytes());
        huge[20..24].copy_from_slice(&20000u32.to_be_bytes());
        let crc = crc32fast::hash(&huge[12..29]);
        huge[29..33].copy_from_slice(&crc.to_be_bytes());
        let err = decode("huge.png", &huge, sizes(8, 0)).unwrap_err();
        assert!(matches!(err, DecodeError::Size { width: 20000, height: 20000, .. }), "{err}");
        let mut cut = png(16, 16);
        cut.truncate(cut.len() - 30);
        assert!(matches!(decode("cut.png", &cut, sizes(8, 0)), Err(DecodeError::Corrupt { .. })));
        let err = decode("strip.png", &png(1, 4000), sizes(8, 0)).unwrap_err();
        assert!(matches!(err, DecodeError::Strip { width: 1, height: 4000, .. }), "{err}");
        assert!(decode("wide.png", &png(160, 10), sizes(8, 0)).is_ok(), "16:1 is still a photo");
    }

    #[test]
    fn keeps_the_masks_guide_at_most_the_mask_size() {
        let sized = |mask| Sizes { res: 10, multiple: None, detail: 0, mask, detect: 0 };
        let guide = |bytes: &[u8], mask| decode("a.png", bytes, sized(mask)).unwrap().guide;
        assert_eq!(guide(&png(40, 20), 16).unwrap().dimensions(), (16, 8));
        assert_eq!(guide(&png(40, 20), 64).unwrap().dimensions(), (40, 20), "never enlarged");
        assert!(guide(&png(40, 20), 0).is_none());
    }

    /// A 40×20 JPEG whose EXIF says to turn it a quarter clockwise (orientation 6) and that a
    /// 35 mm-equivalent 30 mm lens took it.
    fn turned_jpeg() -> Vec<u8> {
        use crate::stages::exif::tests::{field, raw_exif};
        use ::exif::{Tag, Value};
        use image::ImageEncoder;
        let img = RgbImage::from_fn(40, 20, |x, _| image::Rgb([if x < 20 { 250 } else { 5 }; 3]));
        let raw = raw_exif(&[
            field(Tag::Orientation, Value::Short(vec![6])),
            field(Tag::FocalLengthIn35mmFilm, Value::Short(vec![30])),
        ]);
        let mut out = Cursor::new(Vec::new());
        let mut jpeg = image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, 95);
        jpeg.set_exif_metadata(raw).unwrap();
        jpeg.write_image(img.as_raw(), 40, 20, image::ExtendedColorType::Rgb8).unwrap();
        out.into_inner()
    }

    #[test]
    fn turns_a_photo_upright_and_reads_its_focal_length() {
        let m = decode("t.jpg", &turned_jpeg(), sizes(10, 0)).unwrap();
        assert_eq!((m.letterbox.width, m.letterbox.height), (20, 40), "turned upright");
        // 30 / 43.27 of the 44.7 px diagonal.
        let f = m.exif_focal.unwrap();
        assert!((f - 31.0).abs() < 0.1, "{f}");
        assert_eq!(decode("a.png", &png(40, 20), sizes(10, 0)).unwrap().exif_focal, None);
    }

    #[test]
    fn a_portable_copy_is_the_photo_itself_or_its_upright_pixels() {
        let plain = png(40, 20);
        assert_eq!(portable_photo("a.png", &plain).unwrap(), (plain, "png"));
        // A turned JPEG is written upright as PNG: the bright half, left in the stored image,
        // is on top once turned clockwise.
        let (bytes, ext) = portable_photo("t.jpg", &turned_jpeg()).unwrap();
        let copy = image::load_from_memory(&bytes).unwrap().into_rgb8();
        assert_eq!((ext, copy.dimensions()), ("png", (20, 40)));
        assert!(copy.get_pixel(10, 5)[0] > 200 && copy.get_pixel(10, 35)[0] < 50);
        assert!(matches!(portable_photo("j.jpg", b"junk"), Err(DecodeError::Format { .. })));
    }

    #[test]
    fn reads_16_bit_grey_and_cmyk_photos_and_names_the_formats_it_does_not() {
        let mut out = Cursor::new(Vec::new());
        let deep = image::ImageBuffer::<image::Rgb<u16>, _>::from_fn(8, 4, |x, _| {
            image::Rgb([x as u16 * 8000, 0, 65535])
        });
        deep.write_to(&mut out, image::ImageFormat::Png).unwrap();
        let (rgb, _) = decode_rgb("deep.png", &out.into_inner()).unwrap();
        assert_eq!(rgb.get_pixel(7, 0).0, [218, 0, 255], "16 bits scaled to 8");
        let mut out = Cursor::new(Vec::new());
        image::GrayImage::from_pixel(8, 4, image::Luma([77]))
            .write_to(&mut out, image::ImageFormat::Jpeg)
            .unwrap();
        let (rgb, _) = decode_rgb("grey.jpg", &out.into_inner()).unwrap();
        let p = rgb.get_pixel(3, 2).0;
        assert!(p.iter().all(|&c| c.abs_diff(77) <= 2), "grey on all three channels: {p:?}");
        // A CMYK JPEG (made by Pillow): red on the left, blue on the right.
        let cmyk = std::fs::read(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/cmyk.jpg"));
        let (rgb, _) = decode_rgb("cmyk.jpg", &cmyk.unwrap()).unwrap();
        let (left, right) = (rgb.get_pixel(3, 8).0, rgb.get_pixel(20, 8).0);
        assert!(
            left[0] > 200 && left[2] < 60 && right[2] > 200 && right[0] < 60,
            "{left:?} {right:?}"
        );
        // A phone's HEIC (its ftyp box), and a TIFF: refused by name, not as garbage.
        let heic = b"\0\0\0\x18ftypheic\0\0\0\0mif1heic\0\0\0\0";
        let err = decode_rgb("IMG_0001.HEIC", heic).unwrap_err();
        assert!(
            matches!(&err, DecodeError::Unsupported { format, .. } if format == "HEIC"),
            "{err}"
        );
        assert!(err.to_string().starts_with("IMG_0001.HEIC: HEIC images are not supported"));
        let tiff = [b"II*\0".as_slice(), &[8, 0, 0, 0], &[0; 32]].concat();
        let err = decode_rgb("scan.tif", &tiff).unwrap_err();
        assert!(
            matches!(&err, DecodeError::Unsupported { format, .. } if format == "TIFF"),
            "{err}"
        );
    }
}

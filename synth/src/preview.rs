//! A contact sheet of one scene for people to look at: up to eight frames spread over the
//! path, one column each, with rows RGB, depth (near = bright, far = dark, scaled to the
//! scene's depth range) and instances (a fixed colour per id, background black).

use image::{Rgb, RgbImage};
use inssplat_proto::dataset::Scene;

use super::texture::hash2;

/// Frames shown at most.
const COLUMNS: usize = 8;

/// The sheet; each tile is the frame size scaled by an integer to at least 128 px high.
pub fn contact_sheet(scene: &Scene) -> RgbImage {
    let n = scene.frames.len().min(COLUMNS);
    let picks: Vec<usize> = (0..n).map(|i| i * scene.frames.len() / n.max(1)).collect();
    let (w, h) = scene.frames.first().map_or((1, 1), |f| (f.width(), f.height()));
    let zoom = 128u32.div_ceil(h).max(1);
    let (tw, th) = (w * zoom, h * zoom);
    let gap = 2;
    let mut sheet = RgbImage::from_pixel(
        n as u32 * (tw + gap) + gap,
        3 * (th + gap) + gap,
        Rgb([255, 255, 255]),
    );
    let max_depth = scene
        .frames
        .iter()
        .filter_map(|f| f.depth.as_ref())
        .flat_map(|d| d.iter().copied())
        .fold(0.0f32, f32::max)
        .max(1e-3);
    for (col, &fi) in picks.iter().enumerate() {
        let f = &scene.frames[fi];
        let x0 = gap + col as u32 * (tw + gap);
        for y in 0..th {
            for x in 0..tw {
                let p = ((y / zoom) * w + x / zoom) as usize;
                let rgb = Rgb([f.rgb[3 * p], f.rgb[3 * p + 1], f.rgb[3 * p + 2]]);
                sheet.put_pixel(x0 + x, gap + y, rgb);
                let d = f.depth.as_ref().map_or(0.0, |d| d[p]);
                let v = if d > 0.0 { (255.0 * (1.0 - 0.85 * d / max_depth)) as u8 } else { 0 };
                sheet.put_pixel(x0 + x, 2 * gap + th + y, Rgb([v, v, v]));
                let id = f.instances.as_ref().map_or(0, |i| i[p]);
                sheet.put_pixel(x0 + x, 3 * gap + 2 * th + y, id_colour(id));
            }
        }
    }
    sheet
}

fn id_colour(id: u16) -> Rgb<u8> {
    if id == 0 {
        return Rgb([0, 0, 0]);
    }
    let c = |k: i32| (60.0 + 195.0 * hash2(i32::from(id), k, 0x1d)) as u8;
    Rgb([c(1), c(2), c(3)])
}

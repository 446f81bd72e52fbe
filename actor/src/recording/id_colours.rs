//! A visible colour for every id, so that id images (the simulator's
//! instances, the map's objects) and the map's meshes can be read by eye,
//! and an object has the same colour in the image and in the 3-D view.

/// The colour of `id` as RGB bytes: black for 0 (nothing), otherwise a
/// saturated hue that differs clearly between neighbouring ids (hues step
/// by the golden angle).
pub(crate) fn id_colour(id: u32) -> [u8; 3] {
    if id == 0 {
        return [0, 0, 0];
    }
    const GOLDEN_TURN: f64 = 0.618_033_988_749_895;
    let hue = (f64::from(id) * GOLDEN_TURN).fract() * 6.0;
    // Two brightness levels so that ids whose hues land close stay apart.
    let value = if id.is_multiple_of(2) { 1.0 } else { 0.75 };
    let (sector, within) = (hue.floor() as u8, hue.fract());
    let rising = value * within;
    let falling = value * (1.0 - within);
    let (r, g, b) = match sector {
        0 => (value, rising, 0.0),
        1 => (falling, value, 0.0),
        2 => (0.0, value, rising),
        3 => (0.0, falling, value),
        4 => (rising, 0.0, value),
        _ => (value, 0.0, falling),
    };
    let byte = |c: f64| (c * 255.0).round() as u8;
    [byte(r), byte(g), byte(b)]
}

/// An id image as interleaved RGB bytes in [`id_colour`]'s colours.
pub(crate) fn colour_ids(ids: &[u32]) -> Vec<u8> {
    ids.iter().flat_map(|&id| id_colour(id)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nothing_is_black_and_every_object_is_visible() {
        assert_eq!(id_colour(0), [0, 0, 0]);
        for id in 1..1000 {
            let [r, g, b] = id_colour(id);
            assert!(r.max(g).max(b) >= 190, "id {id} is too dark: {r} {g} {b}");
        }
    }

    #[test]
    fn neighbouring_ids_differ_clearly() {
        for id in 1..200u32 {
            let a = id_colour(id);
            let b = id_colour(id + 1);
            let distance: i32 = a
                .iter()
                .zip(&b)
                .map(|(&x, &y)| (i32::from(x) - i32::from(y)).abs())
                .sum();
            assert!(distance > 120, "ids {id} and {}: {a:?} {b:?}", id + 1);
        }
    }

    #[test]
    fn an_id_image_becomes_three_bytes_a_pixel() {
        let rgb = colour_ids(&[0, 5, 5]);
        assert_eq!(rgb.len(), 9);
        assert_eq!(&rgb[0..3], &[0, 0, 0]);
        assert_eq!(rgb[3..6], rgb[6..9]);
    }
}

//! One scale of a view's table image: the grey image blurred by a Gaussian of `sigma` pixels, its
//! gradient (central differences of the blurred image), and bilinear reads at continuous pixel
//! coordinates (pixel centres at integers). Written here because the alignment needs only these
//! three small operations on `f32` rows; an image crate's blur would add a copy per view and scale.

/// A blurred grey image and its gradient, row-major `width × height`.
pub struct Level {
    pub width: usize,
    pub height: usize,
    pub value: Vec<f32>,
    pub dx: Vec<f32>,
    pub dy: Vec<f32>,
}

impl Level {
    /// `grey` (row-major `width × height`) blurred by `sigma` pixels (separable, edges clamped).
    pub fn new(grey: &[f32], (width, height): (usize, usize), sigma: f64) -> Self {
        let kernel = gaussian(sigma);
        let rows = convolve(grey, (width, height), &kernel, Axis::Rows);
        let value = convolve(&rows, (width, height), &kernel, Axis::Columns);
        let mut dx = vec![0.0; width * height];
        let mut dy = vec![0.0; width * height];
        for y in 0..height {
            for x in 0..width {
                let at = |xx: usize, yy: usize| value[yy * width + xx];
                let (l, r) = (x.saturating_sub(1), (x + 1).min(width - 1));
                let (u, d) = (y.saturating_sub(1), (y + 1).min(height - 1));
                dx[y * width + x] = (at(r, y) - at(l, y)) / (r - l).max(1) as f32;
                dy[y * width + x] = (at(x, d) - at(x, u)) / (d - u).max(1) as f32;
            }
        }
        Self {
            width,
            height,
            value,
            dx,
            dy,
        }
    }

    /// Value and gradient at `(x, y)`, bilinear; `None` within `border` pixels of the edge.
    pub fn read(&self, x: f64, y: f64, border: f64) -> Option<(f64, f64, f64)> {
        let (w, h) = (self.width as f64, self.height as f64);
        if !(x >= border && y >= border && x <= w - 1.0 - border && y <= h - 1.0 - border) {
            return None;
        }
        let (x0, y0) = (x.floor() as usize, y.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(self.width - 1), (y0 + 1).min(self.height - 1));
        let (fx, fy) = (x - x0 as f64, y - y0 as f64);
        let bilinear = |img: &[f32]| {
            let at = |xx: usize, yy: usize| img[yy * self.width + xx] as f64;
            let top = at(x0, y0) * (1.0 - fx) + at(x1, y0) * fx;
            let bottom = at(x0, y1) * (1.0 - fx) + at(x1, y1) * fx;
            top * (1.0 - fy) + bottom * fy
        };
        Some((
            bilinear(&self.value),
            bilinear(&self.dx),
            bilinear(&self.dy),
        ))
    }
}

#[derive(Clone, Copy)]
enum Axis {
    Rows,
    Columns,
}

/// A normalised Gaussian kernel of radius `ceil(3 sigma)`.
fn gaussian(sigma: f64) -> Vec<f32> {
    let r = (3.0 * sigma).ceil().max(1.0) as i64;
    let k: Vec<f64> = (-r..=r)
        .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp())
        .collect();
    let sum: f64 = k.iter().sum();
    k.iter().map(|v| (v / sum) as f32).collect()
}

fn convolve(img: &[f32], (w, h): (usize, usize), kernel: &[f32], axis: Axis) -> Vec<f32> {
    let r = (kernel.len() / 2) as i64;
    let mut out = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            let mut acc = 0.0;
            for (k, &kv) in kernel.iter().enumerate() {
                let o = k as i64 - r;
                let (xx, yy) = match axis {
                    Axis::Rows => ((x as i64 + o).clamp(0, w as i64 - 1) as usize, y),
                    Axis::Columns => (x, (y as i64 + o).clamp(0, h as i64 - 1) as usize),
                };
                acc += kv * img[yy * w + xx];
            }
            out[y * w + x] = acc;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_linear_ramp_keeps_its_slope_under_the_blur_and_reads_exactly_between_pixels() {
        let (w, h) = (40, 30);
        let grey: Vec<f32> = (0..w * h)
            .map(|i| 0.01 * (i % w) as f32 + 0.02 * (i / w) as f32)
            .collect();
        let level = Level::new(&grey, (w, h), 2.0);
        let (v, dx, dy) = level.read(17.25, 12.5, 8.0).expect("inside");
        assert!((v - (0.01 * 17.25 + 0.02 * 12.5)).abs() < 1e-5, "{v}");
        assert!(
            (dx - 0.01).abs() < 1e-5 && (dy - 0.02).abs() < 1e-5,
            "{dx} {dy}"
        );
        assert!(level.read(1.0, 12.0, 2.0).is_none(), "within the border");
    }
}

//! Writes a PNG of a run's predicted depth beside the ground truth and their difference for one test
//! view (debugging aid): `cargo run --release -p trand-cli --example depth_diff -- RUN SEQ t0|t1 FRAME OUT.png`.
fn main() {
    let a: Vec<String> = std::env::args().collect();
    let seq = trand_io::read_sequence_with(
        std::path::Path::new(&a[2]),
        &trand_io::LoadOptions::for_eval(),
    )
    .expect("seq");
    let views = if a[3] == "t1" {
        &seq.test_t1
    } else {
        &seq.test_t0
    };
    let frame: u32 = a[4].parse().expect("frame");
    let v = views.iter().find(|v| v.frame == frame).expect("frame");
    let pred = trand_io::read_npy_f32(&trand_io::run_layout::depth_path(
        std::path::Path::new(&a[1]),
        frame,
    ))
    .expect("npy");
    let gt = v.depth.as_ref().expect("gt");
    let inst = v.instance.as_ref().expect("mask");
    let (w, h) = (gt.width as usize, gt.height as usize);
    let mut img = vec![0u8; w * 3 * h * 3];
    let (lo, hi) = (0.3f32, 0.9f32);
    let grey = |d: f32| {
        if d <= 0.0 {
            0
        } else {
            (255.0 * (1.0 - ((d - lo) / (hi - lo)).clamp(0.0, 1.0))) as u8
        }
    };
    for y in 0..h {
        for x in 0..w {
            let p = y * w + x;
            let (g, q) = (gt.data[p], pred.data[p]);
            let obj = inst.data[p] != 0;
            let row = y * w * 3;
            for c in 0..3 {
                img[(row + x) * 3 + c] = if obj { grey(g) } else { grey(g) / 3 };
                img[(row + w + x) * 3 + c] = grey(q);
            }
            // Difference: red = prediction too far or missing, blue = too near, on object pixels.
            let e = if obj {
                if q <= 0.0 {
                    1.0
                } else {
                    ((q - g) / 0.05).clamp(-1.0, 1.0)
                }
            } else {
                0.0
            };
            let o = (row + 2 * w + x) * 3;
            img[o] = (255.0 * e.max(0.0)) as u8;
            img[o + 2] = (255.0 * (-e).max(0.0)) as u8;
            img[o + 1] = if obj && e == 0.0 { 40 } else { 0 };
        }
    }
    let out = trand_io::Image::from_vec((w * 3) as u32, h as u32, 3, img).expect("size");
    trand_io::write_rgb_png(std::path::Path::new(&a[5]), &out).expect("write");
}

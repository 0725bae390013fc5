//! The CPU reference forward pass, in f32.
//!
//! Why it exists: it is the readable statement of `docs/network.md` in Rust, checked against
//! PyTorch's fixtures, against which the GPU kernels are in turn checked on inputs no fixture
//! covers (many queries, other clouds). So it is written for clarity, not speed: plain loops,
//! one function per layer type, PyTorch weight layouts used as they are. Arithmetic is f32
//! throughout, as in PyTorch (the order of the sums differs from PyTorch's BLAS, which moves
//! results by rounding only; the convolutions sum in the GPU kernel's order, so CPU and GPU agree
//! to a few ulps); the geometry (plane coordinates, cells, bilinear weights) follows
//! the contract operation by operation, because there rounding decides which cell a point is in.

use super::geometry::{plane_uv, Cells, Planes};
use super::weights::{Weights, ENCODER_BLOCKS};

/// `y = W x + b` for a PyTorch Linear (`W` is `[out, in]`), `b` optional.
fn linear(w: &[f32], b: Option<&[f32]>, x: &[f32], out: usize) -> Vec<f32> {
    let n_in = x.len();
    debug_assert_eq!(w.len(), out * n_in);
    (0..out)
        .map(|o| {
            let row = &w[o * n_in..(o + 1) * n_in];
            let mut acc = 0.0f32;
            for (wi, xi) in row.iter().zip(x) {
                acc += wi * xi;
            }
            acc + b.map_or(0.0, |b| b[o])
        })
        .collect()
}

fn relu(x: &[f32]) -> Vec<f32> {
    x.iter().map(|v| v.max(0.0)).collect()
}

/// A Linear layer by state-dict prefix (`{name}.weight`, `{name}.bias`).
fn lin(w: &Weights, name: &str, x: &[f32]) -> Vec<f32> {
    let wt = w.t(&format!("{name}.weight"));
    let out = wt.len() / x.len();
    linear(wt, w.get(&format!("{name}.bias")), x, out)
}

/// `ResBlock`: `shortcut(x) + fc_1(relu(fc_0(relu(x))))`.
fn resblock(w: &Weights, name: &str, x: &[f32]) -> Vec<f32> {
    let hid = lin(w, &format!("{name}.fc_0"), &relu(x));
    let dx = lin(w, &format!("{name}.fc_1"), &relu(&hid));
    let xs = match w.get(&format!("{name}.shortcut.weight")) {
        Some(sc) => linear(sc, None, x, dx.len()),
        None => x.to_vec(),
    };
    xs.iter().zip(&dx).map(|(a, b)| a + b).collect()
}

/// The scattered planes (before the U-Net): the per-point PointNet with local pooling, then
/// the per-cell mean of `fc_c` onto the three planes.
pub fn encode_points(w: &Weights, points: &[[f32; 3]]) -> Planes {
    let cfg = w.config();
    let (r, c_dim, h) = (cfg.reso, cfg.c_dim, cfg.h);
    let cells = Cells::new(points, r, cfg.plane_divisor());
    let mut net: Vec<Vec<f32>> = points.iter().map(|p| resblock(w, "encoder.blocks.0", &lin(w, "encoder.fc_pos", p))).collect();
    for b in 1..ENCODER_BLOCKS {
        // Channel-wise max over each non-empty cell, taken in point order.
        let cell_max: Vec<Vec<f32>> = (0..cells.len())
            .map(|k| {
                let mut m = vec![f32::NEG_INFINITY; h];
                for &p in cells.points_of(k) {
                    for (mi, v) in m.iter_mut().zip(&net[p as usize]) {
                        *mi = mi.max(*v);
                    }
                }
                m
            })
            .collect();
        net = net
            .iter()
            .enumerate()
            .map(|(n, x)| {
                let mut input = x.clone();
                let cs = &cells.cell_of[3 * n..3 * n + 3];
                input.extend((0..h).map(|ch| {
                    // Planes summed in storage order, as PyTorch's `.sum(2)`.
                    let mut s = 0.0f32;
                    for &k in cs {
                        s += cell_max[k as usize][ch];
                    }
                    s
                }));
                resblock(w, &format!("encoder.blocks.{b}"), &input)
            })
            .collect();
    }
    let c: Vec<Vec<f32>> = net.iter().map(|x| lin(w, "encoder.fc_c", x)).collect();
    let mut planes = Planes::zeros(c_dim, r);
    let rr = r * r;
    for k in 0..cells.len() {
        let pts = cells.points_of(k);
        let flat = cells.cell_plane_cell[k] as usize;
        let (plane, cell) = (flat / rr, flat % rr);
        // Mean per channel: the sum in point order, then one division.
        let mut sum = vec![0.0f32; c_dim];
        for &p in pts {
            for (s, v) in sum.iter_mut().zip(&c[p as usize]) {
                *s += v;
            }
        }
        for (ch, s) in sum.iter().enumerate() {
            planes.data[(plane * c_dim + ch) * rr + cell] = s / pts.len() as f32;
        }
    }
    planes
}

/// 3x3 convolution, stride 1, zero padding 1, over `p` images of `[c_in][r][r]`; PyTorch
/// weight `[c_out][c_in][3][3]`. Optionally followed by ReLU.
pub fn conv3x3(x: &[f32], p: usize, c_in: usize, r: usize, wt: &[f32], bias: &[f32], relu: bool) -> Vec<f32> {
    let c_out = bias.len();
    assert_eq!(wt.len(), c_out * c_in * 9);
    assert_eq!(x.len(), p * c_in * r * r);
    let rr = r * r;
    let mut out = vec![0.0f32; p * c_out * rr];
    for img in 0..p {
        for o in 0..c_out {
            let acc = &mut out[(img * c_out + o) * rr..(img * c_out + o + 1) * rr];
            // Sum order: kernel row, input channel, kernel column (the GPU kernel's order).
            for ky in 0..3 {
                // Output rows whose tap row y + ky - 1 is inside.
                let (y0, y1) = (1usize.saturating_sub(ky), (r + 1 - ky).min(r));
                for c in 0..c_in {
                    let src = &x[(img * c_in + c) * rr..(img * c_in + c + 1) * rr];
                    for kx in 0..3 {
                        let wv = wt[((o * c_in + c) * 3 + ky) * 3 + kx];
                        let (x0, x1) = (1usize.saturating_sub(kx), (r + 1 - kx).min(r));
                        for y in y0..y1 {
                            let srow = &src[(y + ky - 1) * r..(y + ky) * r];
                            let arow = &mut acc[y * r..(y + 1) * r];
                            for xx in x0..x1 {
                                arow[xx] += wv * srow[xx + kx - 1];
                            }
                        }
                    }
                }
            }
            for v in acc.iter_mut() {
                *v += bias[o];
                if relu {
                    *v = v.max(0.0);
                }
            }
        }
    }
    out
}

/// 2x2 max pooling, stride 2, over `[p * c][r][r]`.
pub fn maxpool2(x: &[f32], pc: usize, r: usize) -> Vec<f32> {
    let h = r / 2;
    let mut out = vec![0.0f32; pc * h * h];
    for i in 0..pc {
        for y in 0..h {
            for xx in 0..h {
                let at = |dy: usize, dx: usize| x[i * r * r + (2 * y + dy) * r + 2 * xx + dx];
                out[i * h * h + y * h + xx] = at(0, 0).max(at(0, 1)).max(at(1, 0)).max(at(1, 1));
            }
        }
    }
    out
}

/// ConvTranspose2d, kernel 2, stride 2: `[p][c_in][r][r]` → `[p][c_out][2r][2r]`, PyTorch
/// weight `[c_in][c_out][2][2]`, no activation.
pub fn upconv2(x: &[f32], p: usize, c_in: usize, r: usize, wt: &[f32], bias: &[f32]) -> Vec<f32> {
    let c_out = bias.len();
    let r2 = 2 * r;
    let mut out = vec![0.0f32; p * c_out * r2 * r2];
    for img in 0..p {
        for o in 0..c_out {
            for y in 0..r2 {
                for xx in 0..r2 {
                    let (i, j, di, dj) = (y / 2, xx / 2, y % 2, xx % 2);
                    let mut acc = 0.0f32;
                    for c in 0..c_in {
                        acc += x[((img * c_in + c) * r + i) * r + j] * wt[((c * c_out + o) * 2 + di) * 2 + dj];
                    }
                    out[((img * c_out + o) * r2 + y) * r2 + xx] = acc + bias[o];
                }
            }
        }
    }
    out
}

/// 1x1 convolution: `[p][c_in][rr]` → `[p][c_out][rr]`, weight `[c_out][c_in][1][1]`.
pub fn conv1x1(x: &[f32], p: usize, c_in: usize, rr: usize, wt: &[f32], bias: &[f32]) -> Vec<f32> {
    let c_out = bias.len();
    let mut out = vec![0.0f32; p * c_out * rr];
    for img in 0..p {
        for o in 0..c_out {
            for i in 0..rr {
                let mut acc = 0.0f32;
                for c in 0..c_in {
                    acc += x[(img * c_in + c) * rr + i] * wt[o * c_in + c];
                }
                out[(img * c_out + o) * rr + i] = acc + bias[o];
            }
        }
    }
    out
}

/// Channel concatenation per image: `[p][ca][rr]` and `[p][cb][rr]` → `[p][ca + cb][rr]`.
fn concat(a: &[f32], ca: usize, b: &[f32], cb: usize, p: usize, rr: usize) -> Vec<f32> {
    let mut out = Vec::with_capacity(a.len() + b.len());
    for img in 0..p {
        out.extend_from_slice(&a[img * ca * rr..(img + 1) * ca * rr]);
        out.extend_from_slice(&b[img * cb * rr..(img + 1) * cb * rr]);
    }
    out
}

/// The shared U-Net applied to each of the three planes.
pub fn unet(w: &Weights, planes: &Planes) -> Planes {
    let cfg = w.config();
    let d = cfg.unet_depth;
    let conv = |x: &[f32], c_in: usize, r: usize, name: &str| {
        conv3x3(x, 3, c_in, r, w.t(&format!("{name}.weight")), w.t(&format!("{name}.bias")), true)
    };
    let mut x = planes.data.clone();
    let mut c = cfg.c_dim;
    let mut r = cfg.reso;
    let mut skips = Vec::new();
    for k in 0..d {
        if k > 0 {
            x = maxpool2(&x, 3 * c, r);
            r /= 2;
        }
        let f = cfg.filters(k);
        x = conv(&x, c, r, &format!("unet.down.{k}.conv0"));
        x = conv(&x, f, r, &format!("unet.down.{k}.conv1"));
        c = f;
        skips.push(x.clone());
    }
    for k in (0..d - 1).rev() {
        let f = cfg.filters(k);
        let name = format!("unet.up.{k}");
        x = upconv2(&x, 3, c, r, w.t(&format!("{name}.upconv.weight")), w.t(&format!("{name}.upconv.bias")));
        r *= 2;
        x = concat(&x, f, &skips[k], f, 3, r * r);
        x = conv(&x, 2 * f, r, &format!("{name}.conv0"));
        x = conv(&x, f, r, &format!("{name}.conv1"));
        c = f;
    }
    let data = conv1x1(&x, 3, c, r * r, w.t("unet.final.weight"), w.t("unet.final.bias"));
    Planes { c_dim: cfg.c_dim, reso: cfg.reso, data }
}

/// Points (normalised, in [-0.5, 0.5]³) → the planes the decoder samples (after the U-Net).
pub fn encode(w: &Weights, points: &[[f32; 3]]) -> Planes {
    unet(w, &encode_points(w, points))
}

/// The feature `F(q)`: bilinear (align-corners, border-clamped) samples of the three planes,
/// summed in plane order.
pub fn feature(planes: &Planes, divisor: f32, q: [f32; 3]) -> Vec<f32> {
    let (c_dim, r) = (planes.c_dim, planes.reso);
    let rr = r * r;
    let rm1 = (r - 1) as f32;
    let mut f = vec![0.0f32; c_dim];
    for (p, uv) in plane_uv(q, divisor).iter().enumerate() {
        let (x, y) = (uv[0] * rm1, uv[1] * rm1);
        let (x0f, y0f) = (x.floor(), y.floor());
        let (wx, wy) = (x - x0f, y - y0f);
        let (x0, y0) = ((x0f as usize).min(r - 1), (y0f as usize).min(r - 1));
        let (x1, y1) = ((x0 + 1).min(r - 1), (y0 + 1).min(r - 1));
        for (ch, fc) in f.iter_mut().enumerate() {
            let g = |yy: usize, xx: usize| planes.data[(p * c_dim + ch) * rr + yy * r + xx];
            let v = g(y0, x0) * (1.0 - wx) * (1.0 - wy)
                + g(y0, x1) * wx * (1.0 - wy)
                + g(y1, x0) * (1.0 - wx) * wy
                + g(y1, x1) * wx * wy;
            *fc += v;
        }
    }
    f
}

/// The decoder's tensors, looked up once per [`decode`] call.
pub struct Decoder<'a> {
    fc_p: (&'a [f32], &'a [f32]),
    /// Per block: fc_c, fc_0, fc_1 as (weight, bias).
    blocks: Vec<[(&'a [f32], &'a [f32]); 3]>,
    fc_out: (&'a [f32], &'a [f32]),
    h: usize,
}

impl<'a> Decoder<'a> {
    pub fn new(w: &'a Weights) -> Decoder<'a> {
        let l = |name: &str| (w.t(&format!("{name}.weight")), w.t(&format!("{name}.bias")));
        Decoder {
            fc_p: l("decoder.fc_p"),
            blocks: (0..w.config().n_blocks_dec)
                .map(|b| {
                    [
                        l(&format!("decoder.fc_c.{b}")),
                        l(&format!("decoder.blocks.{b}.fc_0")),
                        l(&format!("decoder.blocks.{b}.fc_1")),
                    ]
                })
                .collect(),
            fc_out: l("decoder.fc_out"),
            h: w.config().h_dec,
        }
    }

    /// The occupancy logit of query `q` with feature `feat`:
    /// `net = fc_p(q)`; per block `net = blocks[i](net + fc_c[i](F))`; `fc_out(relu(net))`.
    pub fn logit(&self, q: [f32; 3], feat: &[f32]) -> f32 {
        let h = self.h;
        let mut net = linear(self.fc_p.0, Some(self.fc_p.1), &q, h);
        for [fc, f0, f1] in &self.blocks {
            let c = linear(fc.0, Some(fc.1), feat, h);
            let x: Vec<f32> = net.iter().zip(&c).map(|(a, b)| a + b).collect();
            // ResBlock(h_dec → h_dec): identity shortcut.
            let hid = linear(f0.0, Some(f0.1), &relu(&x), h);
            let dx = linear(f1.0, Some(f1.1), &relu(&hid), h);
            net = x.iter().zip(&dx).map(|(a, b)| a + b).collect();
        }
        linear(self.fc_out.0, Some(self.fc_out.1), &relu(&net), 1)[0]
    }
}

/// Queries (normalised coordinates) → (features `Q × c_dim`, row-major; logits `Q`).
pub fn decode(w: &Weights, planes: &Planes, queries: &[[f32; 3]]) -> (Vec<f32>, Vec<f32>) {
    let cfg = w.config();
    assert_eq!((planes.c_dim, planes.reso), (cfg.c_dim, cfg.reso), "planes do not match the weights");
    let dec = Decoder::new(w);
    let mut features = Vec::with_capacity(queries.len() * cfg.c_dim);
    let mut logits = Vec::with_capacity(queries.len());
    for &q in queries {
        let f = feature(planes, cfg.plane_divisor(), q);
        logits.push(dec.logit(q, &f));
        features.extend_from_slice(&f);
    }
    (features, logits)
}

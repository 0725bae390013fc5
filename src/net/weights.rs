//! Loading the network's weights from a safetensors file, strictly.
//!
//! Why this shape: the sizes of the network live in the file's `__metadata__` (see
//! `docs/network.md`), so the loader first derives a [`NetConfig`] from them, then demands
//! exactly the tensors that config implies — every name present, F32, the PyTorch shape, a byte
//! range inside the file — and nothing else. A file from another training run at other sizes
//! loads without code changes; a truncated, hand-edited or mismatched file is an error naming
//! what is wrong, never a panic or an out-of-bounds read. The tensors are copied out (from
//! little-endian bytes, whatever the alignment) into one `Vec<f32>` so the GPU side can upload
//! them in one buffer.
//!
//! The shipped prior is compiled in ([`PRIOR`]): the browser build has no file system.

use std::collections::BTreeMap;
use std::fmt;

use super::json::{self, Json};

/// Why a weights file could not be used.
#[derive(Clone, Debug, PartialEq)]
pub enum NetError {
    /// The safetensors container itself is malformed (header length, JSON, offsets, coverage).
    Format(String),
    /// `__metadata__` lacks a size or holds one that is not usable.
    Metadata(String),
    /// A tensor is missing, unexpected, or has the wrong dtype, shape or byte range.
    Tensor { name: String, problem: String },
}

impl fmt::Display for NetError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            NetError::Format(s) => write!(f, "malformed safetensors file: {s}"),
            NetError::Metadata(s) => write!(f, "bad network metadata: {s}"),
            NetError::Tensor { name, problem } => write!(f, "tensor \"{name}\": {problem}"),
        }
    }
}

impl std::error::Error for NetError {}

/// The trained prior, built into the binary (native and wasm).
pub const PRIOR: &[u8] = include_bytes!("../../assets/prior.safetensors");

/// The `format` metadata value this code implements.
pub const FORMAT: &str = "nkrr-convonet-1";

/// The encoder's ResBlock count (fixed by the contract, not in the metadata).
pub const ENCODER_BLOCKS: usize = 5;

/// Largest header accepted (the safetensors reference implementation's limit).
const MAX_HEADER: u64 = 100 << 20;
/// Bounds on the sizes, so that a hostile header cannot make us allocate absurd planes or
/// overflow index arithmetic (the tensors themselves are bounded by the file length, but `reso`
/// appears in no tensor shape).
const MAX_WIDTH: usize = 4096;
const MAX_RESO: usize = 2048;
const MAX_DEPTH: usize = 8;
const MAX_BLOCKS: usize = 64;

/// The sizes of the network, from the safetensors `__metadata__`.
#[derive(Clone, Debug, PartialEq)]
pub struct NetConfig {
    /// Encoder hidden width.
    pub h: usize,
    /// Feature (plane channel) count.
    pub c_dim: usize,
    /// Plane resolution R.
    pub reso: usize,
    /// U-Net depth D (levels).
    pub unet_depth: usize,
    /// U-Net start filters f.
    pub unet_filters: usize,
    /// Decoder hidden width.
    pub h_dec: usize,
    /// Decoder block count.
    pub n_blocks_dec: usize,
    /// Plane padding (0.1 by default), as parsed from the metadata string.
    pub padding: f64,
    /// Training step the weights come from, when recorded.
    pub step: Option<u64>,
    /// Held-out IoU recorded at export, when recorded.
    pub heldout_iou: Option<f64>,
}

impl NetConfig {
    /// The built-in prior's sizes, parsed once: the preflight asks for them on every settings
    /// change, and parsing validates every tensor of the 2 MB file.
    pub fn prior() -> Result<NetConfig, NetError> {
        static CONFIG: std::sync::OnceLock<Result<NetConfig, NetError>> = std::sync::OnceLock::new();
        CONFIG.get_or_init(|| Weights::prior().map(|w| w.config().clone())).clone()
    }

    /// Reads and checks the sizes in a safetensors `__metadata__` map.
    pub fn from_metadata(meta: &BTreeMap<String, String>) -> Result<NetConfig, NetError> {
        let get = |key: &str| {
            meta.get(key).ok_or_else(|| NetError::Metadata(format!("\"{key}\" is missing")))
        };
        let size = |key: &str, max: usize| -> Result<usize, NetError> {
            let s = get(key)?;
            let v: usize = s
                .parse()
                .ok()
                .filter(|_| s.bytes().all(|b| b.is_ascii_digit()))
                .ok_or_else(|| NetError::Metadata(format!("\"{key}\" = {s:?} is not a decimal integer")))?;
            if v == 0 || v > max {
                return Err(NetError::Metadata(format!("\"{key}\" = {v} is outside 1..={max}")));
            }
            Ok(v)
        };
        let format = get("format")?;
        if format != FORMAT {
            return Err(NetError::Metadata(format!("\"format\" is {format:?}, this code reads {FORMAT:?}")));
        }
        let cfg = NetConfig {
            h: size("h", MAX_WIDTH)?,
            c_dim: size("c_dim", MAX_WIDTH)?,
            reso: size("reso", MAX_RESO)?,
            unet_depth: size("unet_depth", MAX_DEPTH)?,
            unet_filters: size("unet_filters", MAX_WIDTH)?,
            h_dec: size("h_dec", MAX_WIDTH)?,
            n_blocks_dec: size("n_blocks_dec", MAX_BLOCKS)?,
            padding: {
                let s = get("padding")?;
                let v: f64 = s
                    .parse()
                    .map_err(|_| NetError::Metadata(format!("\"padding\" = {s:?} is not a number")))?;
                if !(0.0..=10.0).contains(&v) {
                    return Err(NetError::Metadata(format!("\"padding\" = {v} is outside [0, 10]")));
                }
                v
            },
            step: match meta.get("step") {
                None => None,
                Some(s) => Some(s.parse().map_err(|_| NetError::Metadata(format!("\"step\" = {s:?} is not an integer")))?),
            },
            heldout_iou: match meta.get("heldout_iou") {
                None => None,
                Some(s) => Some(s.parse().map_err(|_| NetError::Metadata(format!("\"heldout_iou\" = {s:?} is not a number")))?),
            },
        };
        let top = cfg.filters(cfg.unet_depth - 1);
        if top > MAX_WIDTH {
            return Err(NetError::Metadata(format!("the deepest U-Net level has {top} channels (> {MAX_WIDTH})")));
        }
        let step = 1usize << (cfg.unet_depth - 1);
        if !cfg.reso.is_multiple_of(step) {
            return Err(NetError::Metadata(format!(
                "reso {} is not divisible by 2^(unet_depth-1) = {step}",
                cfg.reso
            )));
        }
        Ok(cfg)
    }

    /// Channels of U-Net level `level`: `unet_filters * 2^level`.
    pub fn filters(&self, level: usize) -> usize {
        self.unet_filters << level
    }

    /// `(1 + padding)` rounded to f32: the divisor of the plane coordinates.
    pub fn plane_divisor(&self) -> f32 {
        (1.0 + self.padding) as f32
    }

    /// Every tensor this config implies, with its PyTorch shape, in a fixed order.
    pub fn expected_tensors(&self) -> Vec<(String, Vec<usize>)> {
        let mut t: Vec<(String, Vec<usize>)> = Vec::new();
        let linear = |t: &mut Vec<(String, Vec<usize>)>, name: &str, i: usize, o: usize, bias: bool| {
            t.push((format!("{name}.weight"), vec![o, i]));
            if bias {
                t.push((format!("{name}.bias"), vec![o]));
            }
        };
        let (h, c) = (self.h, self.c_dim);
        linear(&mut t, "encoder.fc_pos", 3, 2 * h, true);
        for b in 0..ENCODER_BLOCKS {
            linear(&mut t, &format!("encoder.blocks.{b}.fc_0"), 2 * h, h, true);
            linear(&mut t, &format!("encoder.blocks.{b}.fc_1"), h, h, true);
            linear(&mut t, &format!("encoder.blocks.{b}.shortcut"), 2 * h, h, false);
        }
        linear(&mut t, "encoder.fc_c", h, c, true);
        let conv = |t: &mut Vec<(String, Vec<usize>)>, name: String, i: usize, o: usize, k: usize| {
            t.push((format!("{name}.weight"), vec![o, i, k, k]));
            t.push((format!("{name}.bias"), vec![o]));
        };
        for k in 0..self.unet_depth {
            let fin = if k == 0 { c } else { self.filters(k - 1) };
            conv(&mut t, format!("unet.down.{k}.conv0"), fin, self.filters(k), 3);
            conv(&mut t, format!("unet.down.{k}.conv1"), self.filters(k), self.filters(k), 3);
        }
        for k in 0..self.unet_depth - 1 {
            let (fi, fo) = (self.filters(k + 1), self.filters(k));
            t.push((format!("unet.up.{k}.upconv.weight"), vec![fi, fo, 2, 2]));
            t.push((format!("unet.up.{k}.upconv.bias"), vec![fo]));
            conv(&mut t, format!("unet.up.{k}.conv0"), 2 * fo, fo, 3);
            conv(&mut t, format!("unet.up.{k}.conv1"), fo, fo, 3);
        }
        conv(&mut t, "unet.final".into(), self.unet_filters, c, 1);
        let hd = self.h_dec;
        linear(&mut t, "decoder.fc_p", 3, hd, true);
        for b in 0..self.n_blocks_dec {
            linear(&mut t, &format!("decoder.fc_c.{b}"), c, hd, true);
        }
        for b in 0..self.n_blocks_dec {
            linear(&mut t, &format!("decoder.blocks.{b}.fc_0"), hd, hd, true);
            linear(&mut t, &format!("decoder.blocks.{b}.fc_1"), hd, hd, true);
        }
        linear(&mut t, "decoder.fc_out", hd, 1, true);
        t
    }
}

/// Where one tensor lives in [`Weights::data`].
#[derive(Clone, Debug, PartialEq)]
pub struct TensorInfo {
    /// Offset in f32 elements.
    pub offset: usize,
    pub shape: Vec<usize>,
}

impl TensorInfo {
    pub fn len(&self) -> usize {
        self.shape.iter().product()
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Validated network weights: the config, the raw metadata, and every tensor.
#[derive(Clone, Debug, PartialEq)]
pub struct Weights {
    config: NetConfig,
    metadata: BTreeMap<String, String>,
    tensors: BTreeMap<String, TensorInfo>,
    data: Vec<f32>,
}

fn fmt_err(s: impl Into<String>) -> NetError {
    NetError::Format(s.into())
}

fn tensor_err(name: &str, problem: impl Into<String>) -> NetError {
    NetError::Tensor { name: name.to_string(), problem: problem.into() }
}

/// A non-negative JSON integer that fits u64 (no sign, fraction or exponent).
fn json_u64(v: &Json) -> Option<u64> {
    match v {
        Json::Num(s) if s.bytes().all(|b| b.is_ascii_digit()) => s.parse().ok(),
        _ => None,
    }
}

/// One header entry, before it is checked against the config.
struct RawTensor {
    shape: Vec<usize>,
    begin: usize,
    end: usize,
}

impl Weights {
    /// The built-in trained prior ([`PRIOR`]).
    pub fn prior() -> Result<Weights, NetError> {
        Weights::from_safetensors(PRIOR)
    }

    /// Parses and validates a safetensors file (see the module documentation for what is
    /// checked).
    pub fn from_safetensors(bytes: &[u8]) -> Result<Weights, NetError> {
        let head: [u8; 8] = bytes
            .get(..8)
            .and_then(|b| b.try_into().ok())
            .ok_or_else(|| fmt_err(format!("{} bytes is too short for the 8-byte header length", bytes.len())))?;
        let n = u64::from_le_bytes(head);
        if n > MAX_HEADER {
            return Err(fmt_err(format!("header length {n} exceeds the {MAX_HEADER}-byte limit")));
        }
        let avail = bytes.len() as u64 - 8;
        if n > avail {
            return Err(fmt_err(format!("header length {n} but only {avail} bytes follow (truncated?)")));
        }
        let n = n as usize;
        let header = &bytes[8..8 + n];
        let data = &bytes[8 + n..];
        let root = json::parse(header).map_err(|e| fmt_err(format!("header is not valid JSON: {e}")))?;
        let Json::Obj(members) = root else {
            return Err(fmt_err(format!("header is {}, not an object", root.kind())));
        };

        let mut metadata = BTreeMap::new();
        let mut raw: BTreeMap<String, RawTensor> = BTreeMap::new();
        for (name, v) in members {
            if name == "__metadata__" {
                let Json::Obj(m) = v else {
                    return Err(NetError::Metadata(format!("__metadata__ is {}, not an object", v.kind())));
                };
                for (k, v) in m {
                    let Json::Str(s) = v else {
                        return Err(NetError::Metadata(format!("\"{k}\" is {}, not a string", v.kind())));
                    };
                    metadata.insert(k, s);
                }
                continue;
            }
            let t = Self::raw_tensor(&name, &v, data.len())?;
            raw.insert(name, t);
        }

        // The byte ranges must tile the data section exactly, as the reference implementation
        // requires: no gaps, no overlaps, nothing after the last tensor.
        let mut ranges: Vec<(usize, usize, &str)> = raw.iter().map(|(k, t)| (t.begin, t.end, k.as_str())).collect();
        ranges.sort();
        let mut at = 0usize;
        for &(b, e, name) in &ranges {
            if b != at {
                return Err(tensor_err(
                    name,
                    format!("data_offsets start at {b} but the previous tensor ends at {at} (gap or overlap)"),
                ));
            }
            at = e;
        }
        if at != data.len() {
            return Err(fmt_err(format!("the tensors cover {at} data bytes but the file holds {}", data.len())));
        }

        let config = NetConfig::from_metadata(&metadata)?;
        let expected = config.expected_tensors();
        for name in raw.keys() {
            if !expected.iter().any(|(n, _)| n == name) {
                return Err(tensor_err(name, "unexpected for this config (metadata sizes do not match the tensors?)"));
            }
        }
        let total: usize = expected.iter().map(|(_, s)| s.iter().product::<usize>()).sum();
        let mut out = Vec::with_capacity(total);
        let mut tensors = BTreeMap::new();
        for (name, shape) in expected {
            let t = raw.get(&name).ok_or_else(|| tensor_err(&name, "missing"))?;
            if t.shape != shape {
                return Err(tensor_err(&name, format!("shape {:?}, the config implies {:?}", t.shape, shape)));
            }
            let offset = out.len();
            out.extend(data[t.begin..t.end].chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])));
            tensors.insert(name, TensorInfo { offset, shape });
        }
        Ok(Weights { config, metadata, tensors, data: out })
    }

    fn raw_tensor(name: &str, v: &Json, data_len: usize) -> Result<RawTensor, NetError> {
        let Json::Obj(fields) = v else {
            return Err(tensor_err(name, format!("entry is {}, not an object", v.kind())));
        };
        let field = |key: &str| {
            fields
                .iter()
                .find(|(k, _)| k == key)
                .map(|(_, v)| v)
                .ok_or_else(|| tensor_err(name, format!("\"{key}\" is missing")))
        };
        if let Some((k, _)) = fields.iter().find(|(k, _)| !matches!(k.as_str(), "dtype" | "shape" | "data_offsets")) {
            return Err(tensor_err(name, format!("unknown field \"{k}\"")));
        }
        match field("dtype")? {
            Json::Str(s) if s == "F32" => {}
            Json::Str(s) => return Err(tensor_err(name, format!("dtype {s}, only F32 is supported"))),
            other => return Err(tensor_err(name, format!("dtype is {}, not a string", other.kind()))),
        }
        let Json::Arr(dims) = field("shape")? else {
            return Err(tensor_err(name, "shape is not an array"));
        };
        let mut shape = Vec::with_capacity(dims.len());
        let mut elems: u64 = 1;
        for d in dims {
            let d = json_u64(d).ok_or_else(|| tensor_err(name, "shape holds something other than a non-negative integer"))?;
            elems = elems.checked_mul(d).ok_or_else(|| tensor_err(name, "shape overflows"))?;
            shape.push(usize::try_from(d).map_err(|_| tensor_err(name, "shape overflows"))?);
        }
        let Json::Arr(offs) = field("data_offsets")? else {
            return Err(tensor_err(name, "data_offsets is not an array"));
        };
        let [b, e] = offs.as_slice() else {
            return Err(tensor_err(name, format!("data_offsets has {} entries, not 2", offs.len())));
        };
        let (b, e) = match (json_u64(b), json_u64(e)) {
            (Some(b), Some(e)) => (b, e),
            _ => return Err(tensor_err(name, "data_offsets holds something other than a non-negative integer")),
        };
        if b > e || e > data_len as u64 {
            return Err(tensor_err(
                name,
                format!("data_offsets [{b}, {e}] outside the {data_len}-byte data section (truncated file?)"),
            ));
        }
        let bytes = elems.checked_mul(4).ok_or_else(|| tensor_err(name, "shape overflows"))?;
        if e - b != bytes {
            return Err(tensor_err(name, format!("data_offsets span {} bytes, shape {shape:?} needs {bytes}", e - b)));
        }
        Ok(RawTensor { shape, begin: b as usize, end: e as usize })
    }

    pub fn config(&self) -> &NetConfig {
        &self.config
    }

    /// The raw `__metadata__` strings.
    pub fn metadata(&self) -> &BTreeMap<String, String> {
        &self.metadata
    }

    /// Tensor names, sorted.
    pub fn names(&self) -> impl Iterator<Item = &str> {
        self.tensors.keys().map(|s| s.as_str())
    }

    /// Where `name` lives in [`Weights::data`], if it exists.
    pub fn info(&self, name: &str) -> Option<&TensorInfo> {
        self.tensors.get(name)
    }

    /// The values of tensor `name` (PyTorch layout, row-major), if it exists.
    pub fn get(&self, name: &str) -> Option<&[f32]> {
        self.tensors.get(name).map(|t| &self.data[t.offset..t.offset + t.len()])
    }

    /// The shape of tensor `name`, if it exists.
    pub fn shape(&self, name: &str) -> Option<&[usize]> {
        self.tensors.get(name).map(|t| t.shape.as_slice())
    }

    /// The values of tensor `name`, or an error naming it.
    pub fn tensor(&self, name: &str) -> Result<&[f32], NetError> {
        self.get(name).ok_or_else(|| tensor_err(name, "missing"))
    }

    /// All tensors, concatenated (see [`Weights::info`] for offsets).
    pub fn data(&self) -> &[f32] {
        &self.data
    }

    /// A tensor the config guarantees (loading checked it), for the forward passes.
    pub(crate) fn t(&self, name: &str) -> &[f32] {
        self.get(name).unwrap_or_else(|| panic!("tensor {name} was validated at load"))
    }
}

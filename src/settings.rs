//! Every setting of a reconstruction, defined once.
//!
//! [`TABLE`] holds, for each setting, its JS option and share-link key, its command-line flag,
//! its form label, one line of help, its kind and range, and its default; everything else is
//! derived from it: [`Settings::default`], the CLI's parsing and usage text (`src/bin/nkrr/`, whose own flags are the table in `args.rs`),
//! the wasm API's options and the page's form and share links (`settings_table` in
//! `src/web/page_api.rs`, read by `web/settings.js`). A default or a range written anywhere else is a
//! bug: `tests/settings.rs` and `tests/browser/settings.test.mjs` check that the CLI, the JS API
//! and the page offer the same settings with the same defaults and ranges. (In the spirit of
//! ripgrep's one list of flags.)
//!
//! [`Settings`] is what the user asked for; what the program decides from it to fit the machine
//! (a subsample, fewer inducing points) is [`crate::plan::MemoryPlan`]'s, and never written back
//! here.

use crate::units::Units;
use crate::io::gltf::Compression;

/// Which field the surface is the level set of.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Method {
    /// The network prior alone: occupancy sigmoid(l(q)).
    Network,
    /// The paper's method: Nyström KRR on the network's features, tuned to the shape.
    Nkrr,
}

/// Where the kernel regression's objective and gradient are computed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum KrrBackend {
    /// The GPU on real GPUs; the f64 CPU reference on software adapters (lavapipe,
    /// SwiftShader), where the GPU path's exact fixed-point Gram matrix is measured to be ~5x
    /// slower than the CPU (docs/krr.md).
    Auto,
    Gpu,
    Cpu,
}

impl KrrBackend {
    /// Whether the objective runs on the GPU, on an adapter that is (`software`) or is not a
    /// software one.
    pub fn on_gpu(self, software: bool) -> bool {
        match self {
            KrrBackend::Gpu => true,
            KrrBackend::Cpu => false,
            KrrBackend::Auto => !software,
        }
    }
}

/// What the kernel regression adds to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PriorMean {
    /// The field is l(q) + g(q), g fitted to the residual of the network's logit: where the data
    /// says nothing, the field is the network's, so the tuned field cannot stray far from the
    /// network where the network was right (the default).
    Network,
    /// The field is g(q) alone, which decays to 0, the surface level, away from the inducing
    /// points (the paper).
    Zero,
}

/// Whether a cloud is reconstructed in tiles ([`crate::scene`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Tiles {
    /// Tiles when the cloud spans a scene ([`crate::scene::SCENE_EXTENT_M`] or more).
    Auto,
    On,
    Off,
}

/// How the mesh is made from the field ([`crate::poisson`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Surface {
    /// Poisson from [`crate::plan::POISSON_POINTS`] points up, the field's level set below.
    Auto,
    /// The field's zero level set.
    Field,
    /// A screened Poisson solve through the points, with normals the field orients.
    Poisson,
}

/// Which of the tuning's iterates is kept.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SelectBy {
    /// The lowest error on held-out pairs, which also stops the tuning once it no longer falls.
    HeldOut,
    /// The lowest training error (the paper).
    Training,
}

/// Everything a reconstruction can be told. The defaults are [`TABLE`]'s (the paper's where it
/// has one); see each entry there for what a field means and its range.
#[derive(Clone, Debug, PartialEq)]
pub struct Settings {
    pub method: Method,
    pub resolution: u32,
    pub remove_small_components: Option<f32>,
    pub min_support: Option<f64>,
    pub outliers: Option<f32>,
    pub max_points: usize,
    pub m: usize,
    pub steps: usize,
    pub lr: f64,
    pub tune_pairs: Option<usize>,
    pub select_by: SelectBy,
    pub prior_mean: PriorMean,
    pub lambda: f64,
    pub tune_theta: bool,
    pub tune_z: bool,
    pub knn_k: usize,
    pub near_k: Option<usize>,
    pub extra_pairs: Option<usize>,
    pub across: Option<f32>,
    pub label_clip: Option<f32>,
    pub euclidean: bool,
    pub position: bool,
    pub krr_backend: KrrBackend,
    pub trim: Option<f32>,
    pub triangles: Option<usize>,
    pub max_error: Option<f32>,
    pub glb: Compression,
    pub fit: bool,
    pub fit_noise: bool,
    pub colors: bool,
    pub units: Option<Units>,
    pub tiles: Tiles,
    pub surface: Surface,
    pub detail: Option<f32>,
    pub one_layer: bool,
    /// A scene's tiles tune the kernel regression on their points (with [`Method::Nkrr`]);
    /// off, they use the network's field, several times faster (docs/scenes.md).
    pub tile_regression: bool,
}

impl Settings {
    /// How the extra training points are drawn around `n` input points.
    pub fn offsets(&self, n: usize) -> crate::sample::Offsets {
        crate::sample::Offsets {
            k: self.knn_k,
            near_k: self.near_k,
            per_point: crate::sample::Offsets::per_point_for(n, self.extra_pairs),
        }
    }

    /// Training points per input point beyond the point itself: the offsets' and, with
    /// [`Settings::across`], the two across the surface.
    pub fn extra_per_point(&self, n: usize) -> usize {
        self.offsets(n).per_point + if self.across.is_some() { 2 } else { 0 }
    }

    /// Training pairs for `n` input points: each point and its [`Settings::extra_per_point`].
    pub fn training_pairs(&self, n: usize) -> usize {
        n * (1 + self.extra_per_point(n))
    }
}

impl Default for Settings {
    fn default() -> Self {
        // Placeholders only: every field is then set from its TABLE entry's default (the test
        // `every_field_has_one_entry` checks that each one is).
        let mut s = Settings {
            method: Method::Network,
            resolution: 0,
            remove_small_components: None,
            min_support: None,
            outliers: None,
            max_points: 0,
            m: 0,
            steps: 0,
            lr: 0.0,
            tune_pairs: None,
            select_by: SelectBy::Training,
            prior_mean: PriorMean::Zero,
            lambda: 0.0,
            tune_theta: false,
            tune_z: false,
            knn_k: 0,
            near_k: None,
            extra_pairs: None,
            across: None,
            label_clip: None,
            euclidean: false,
            position: false,
            krr_backend: KrrBackend::Auto,
            trim: None,
            triangles: None,
            max_error: None,
            glb: Compression::None,
            fit: false,
            fit_noise: false,
            colors: false,
            units: None,
            tiles: Tiles::Auto,
            surface: Surface::Auto,
            detail: None,
            one_layer: false,
            tile_regression: false,
        };
        for def in TABLE {
            (def.set)(&mut s, def.default);
        }
        s
    }
}

/// A setting's value, as the table speaks of it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Value {
    /// Off: a setting that can be off (see [`Setting::can_be_off`]) or a choice with no value.
    Off,
    Bool(bool),
    Num(f64),
    Choice(&'static str),
}

/// What values a setting takes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Kind {
    /// A whole number in `min..=max`.
    Int { min: f64, max: f64 },
    /// A number in `min..=max`.
    Float { min: f64, max: f64 },
    /// One of (value, label); a setting whose default is [`Value::Off`] lists "" (off) among them.
    Choice(&'static [(&'static str, &'static str)]),
    /// On or off. Its CLI flag sets the opposite of the default (`--no-colors`, `--euclidean`).
    Switch,
}

/// One setting: everything the CLI, the JS API, share links and the page's form need.
pub struct Setting {
    /// The JS option and share-link parameter (camelCase).
    pub key: &'static str,
    /// The command-line flag.
    pub flag: &'static str,
    /// The form's label.
    pub label: &'static str,
    /// One line of help (the CLI's usage, the form's hint).
    pub help: &'static str,
    pub kind: Kind,
    pub default: Value,
    /// A number setting that can be off: 0 (JS, links, forms) or [`Setting::off_flag`] turns
    /// it off.
    pub can_be_off: bool,
    /// The CLI flag that turns it off (`--no-label-clip`).
    pub off_flag: Option<&'static str>,
    /// The value the CLI flag takes when no number follows it (`--trim` alone).
    pub bare: Option<f64>,
    /// Other CLI flags that set a fixed value (`--no-tune` is `--steps 0`).
    pub aliases: &'static [(&'static str, f64)],
    /// Suggested values for the page's menu (empty: a number field).
    pub presets: &'static [(f64, &'static str)],
    /// Only meaningful with [`Method::Nkrr`] (the page hides it for the network).
    pub nkrr_only: bool,
    /// Only meaningful for a GLB output (how the GLB stores the mesh).
    pub glb_only: bool,
    /// Behind the page's "Advanced settings" (ablations, tuning knobs).
    pub advanced: bool,
    get: fn(&Settings) -> Value,
    set: fn(&mut Settings, Value),
}

/// What an entry leaves unsaid: no off flag, alias, presets or bare value, shown for both
/// methods, not advanced. Every entry sets its own key, flag, help, kind, default, get and set.
const BASE: Setting = Setting {
    key: "",
    flag: "",
    label: "",
    help: "",
    kind: Kind::Switch,
    default: Value::Off,
    can_be_off: false,
    off_flag: None,
    bare: None,
    aliases: &[],
    presets: &[],
    nkrr_only: false,
    glb_only: false,
    advanced: false,
    get: |_| Value::Off,
    set: |_, _| {},
};

fn num(v: Value) -> f64 {
    match v {
        Value::Num(x) => x,
        _ => 0.0,
    }
}

fn opt_f32(v: Value) -> Option<f32> {
    match v {
        Value::Num(x) => Some(x as f32),
        _ => None,
    }
}

fn opt_usize(v: Value) -> Option<usize> {
    match v {
        Value::Num(x) => Some(x as usize),
        _ => None,
    }
}

fn from_opt_usize(v: Option<usize>) -> Value {
    v.map_or(Value::Off, |n| Value::Num(n as f64))
}

fn from_opt(v: Option<f32>) -> Value {
    v.map_or(Value::Off, |x| Value::Num(x as f64))
}

fn flag(v: Value) -> bool {
    v == Value::Bool(true)
}

fn choice(v: Value) -> &'static str {
    match v {
        Value::Choice(s) => s,
        _ => "",
    }
}

/// Every setting, in the order the page and the usage text show them.
pub static TABLE: &[Setting] = &[
    Setting {
        key: "method",
        flag: "--method",
        label: "Method",
        help: "the field to mesh: nkrr (the paper's tuned kernel regression) or the network prior alone",
        kind: Kind::Choice(&[("nkrr", "NKRR (paper)"), ("network", "Network prior")]),
        default: Value::Choice("nkrr"),
        get: |s| Value::Choice(match s.method {
            Method::Nkrr => "nkrr",
            Method::Network => "network",
        }),
        set: |s, v| s.method = if choice(v) == "network" { Method::Network } else { Method::Nkrr },
        ..BASE
    },
    Setting {
        key: "m",
        flag: "--m",
        label: "Inducing points m",
        help: "inducing points of the Nyström KRR (paper: 500; 1000 slightly better; 5000 overfits)",
        kind: Kind::Int { min: 1.0, max: 5000.0 },
        default: Value::Num(500.0),
        nkrr_only: true,
        get: |s| Value::Num(s.m as f64),
        set: |s, v| s.m = num(v) as usize,
        ..BASE
    },
    Setting {
        key: "steps",
        flag: "--steps",
        label: "Tuning steps",
        help: "Adam steps of the test-time tuning (paper: 100; 0: no tuning)",
        kind: Kind::Int { min: 0.0, max: 1000.0 },
        // With lr 0.3, 30 steps give the meshes of the paper's 100 at lr 0.1 (docs/speed.md).
        default: Value::Num(30.0),
        aliases: &[("--no-tune", 0.0)],
        nkrr_only: true,
        get: |s| Value::Num(s.steps as f64),
        set: |s, v| s.steps = num(v) as usize,
        ..BASE
    },
    Setting {
        key: "lr",
        flag: "--lr",
        label: "Tuning learning rate",
        help: "Adam's learning rate in the test-time tuning (paper: 0.1)",
        kind: Kind::Float { min: 1e-4, max: 10.0 },
        default: Value::Num(0.3),
        nkrr_only: true,
        advanced: true,
        get: |s| Value::Num(s.lr),
        set: |s, v| s.lr = num(v),
        ..BASE
    },
    Setting {
        key: "tunePairs",
        flag: "--tune-pairs",
        label: "Pairs for tuning",
        help: "tune on a stratified subsample of this many training pairs, then solve on all of them; off tunes on all pairs (the paper)",
        kind: Kind::Int { min: 16.0, max: 10_000_000.0 },
        default: Value::Num(4000.0),
        can_be_off: true,
        off_flag: Some("--all-pairs"),
        nkrr_only: true,
        advanced: true,
        get: |s| from_opt_usize(s.tune_pairs),
        set: |s, v| s.tune_pairs = opt_usize(v),
        ..BASE
    },
    Setting {
        key: "selectBy",
        flag: "--select-by",
        label: "Keep the iterate with",
        help: "which tuning iterate is kept: the lowest error on held-out pairs (and stop when it stops falling), or the lowest training error (the paper)",
        kind: Kind::Choice(&[("heldout", "lowest held-out error"), ("training", "lowest training error (paper)")]),
        default: Value::Choice("heldout"),
        nkrr_only: true,
        advanced: true,
        get: |s| Value::Choice(match s.select_by {
            SelectBy::HeldOut => "heldout",
            SelectBy::Training => "training",
        }),
        set: |s, v| s.select_by = if choice(v) == "training" { SelectBy::Training } else { SelectBy::HeldOut },
        ..BASE
    },
    Setting {
        key: "priorMean",
        flag: "--prior-mean",
        label: "Regression adds to",
        help: "network: the regression fits the residual of the network's logit (the label clip does not apply), so the field is the network's where the data says nothing and the tuned field stays close to the network's; zero: the field is the regression alone (the paper)",
        kind: Kind::Choice(&[("network", "the network's logit"), ("zero", "nothing (paper)")]),
        // The network: measured on the eval clouds at 500, 1,000 and 1,500 points (where the
        // regression is tuned), the regression alone lost to the network by more than 0.01 CD1
        // x100 on two clouds (suzanne-500, teapot-1k) and the residual on none (docs/results.md,
        // "The network as the prior mean, the default").
        default: Value::Choice("network"),
        nkrr_only: true,
        advanced: true,
        get: |s| Value::Choice(match s.prior_mean {
            PriorMean::Network => "network",
            PriorMean::Zero => "zero",
        }),
        set: |s, v| s.prior_mean = if choice(v) == "network" { PriorMean::Network } else { PriorMean::Zero },
        ..BASE
    },
    Setting {
        key: "resolution",
        flag: "--resolution",
        label: "Resolution",
        help: "marching-cubes resolution over the padded unit cube (128 is about ConvONet's output)",
        kind: Kind::Int { min: 16.0, max: crate::mesh::refine::MAX_RESOLUTION as f64 },
        default: Value::Num(128.0),
        presets: &[(64.0, "64³"), (96.0, "96³"), (128.0, "128³"), (192.0, "192³"), (256.0, "256³")],
        get: |s| Value::Num(s.resolution as f64),
        set: |s, v| s.resolution = num(v) as u32,
        ..BASE
    },
    Setting {
        key: "surface",
        flag: "--surface",
        label: "Surface",
        help: "the mesh from the field's level set, or from a screened Poisson solve through the points with normals the field orients (closer on clean scans; auto: Poisson from 1000 points up)",
        kind: Kind::Choice(&[("auto", "auto"), ("field", "the field's level set"), ("poisson", "screened Poisson, oriented by the field")]),
        default: Value::Choice("auto"),
        get: |s| Value::Choice(match s.surface {
            Surface::Auto => "auto",
            Surface::Field => "field",
            Surface::Poisson => "poisson",
        }),
        set: |s, v| {
            s.surface = match choice(v) {
                "field" => Surface::Field,
                "poisson" => Surface::Poisson,
                _ => Surface::Auto,
            }
        },
        ..BASE
    },
    Setting {
        key: "removeSmall",
        flag: "--remove-small",
        label: "Remove small pieces",
        help: "drop components with fewer than this fraction of the largest one's triangles",
        kind: Kind::Float { min: 0.0, max: 1.0 },
        default: Value::Off,
        can_be_off: true,
        presets: &[(0.0, "Off"), (0.01, "< 1% of the largest"), (0.05, "< 5% of the largest"), (0.2, "< 20% of the largest")],
        get: |s| from_opt(s.remove_small_components),
        set: |s, v| s.remove_small_components = opt_f32(v),
        ..BASE
    },
    Setting {
        key: "outliers",
        flag: "--outliers",
        label: "Drop stray points",
        help: "drop points whose mean distance to their 20 nearest neighbours is more than this many times the median of the same over their 100 nearest (stray points; a sparse but even scan stays), and the few points (at most 1 %) that lie apart beyond empty space wider than the rest of the cloud; off keeps every point",
        kind: Kind::Float { min: 1.0, max: 100.0 },
        default: Value::Num(2.0),
        can_be_off: true,
        off_flag: Some("--keep-outliers"),
        advanced: true,
        get: |s| from_opt(s.outliers),
        set: |s, v| s.outliers = opt_f32(v),
        ..BASE
    },
    Setting {
        key: "minSupport",
        flag: "--min-support",
        label: "Drop unsupported pieces",
        help: "drop the mesh's pieces that are nearest to fewer than this fraction of the points (floating blobs around stray points); the best-supported piece always stays; off keeps every piece",
        kind: Kind::Float { min: 1e-6, max: 1.0 },
        default: Value::Num(0.005),
        can_be_off: true,
        off_flag: Some("--keep-pieces"),
        advanced: true,
        // f64: 0.005 has no exact f32, and a setting must read back as its default.
        get: |s| s.min_support.map_or(Value::Off, Value::Num),
        set: |s, v| s.min_support = match v {
            Value::Num(x) => Some(x),
            _ => None,
        },
        ..BASE
    },
    Setting {
        key: "units",
        flag: "--units",
        label: "Units of the cloud",
        help: "the cloud's length unit: the mesh is scaled to metres (glTF's unit); unset keeps coordinates as they are",
        kind: Kind::Choice(&[
            ("", "As in the file"),
            ("mm", "millimetres"),
            ("cm", "centimetres"),
            ("m", "metres"),
            ("in", "inches"),
            ("ft", "feet"),
        ]),
        default: Value::Off,
        get: |s| s.units.map_or(Value::Off, |u| Value::Choice(u.code())),
        set: |s, v| s.units = choice(v).parse().ok(),
        ..BASE
    },
    Setting {
        key: "tiles",
        flag: "--tiles",
        label: "Scene tiles",
        help: "reconstruct in overlapping tiles of about an object's worth of points, blended into one mesh (auto: when the cloud spans 5 m or more, in metres per --units; on for a smaller room)",
        kind: Kind::Choice(&[("auto", "auto"), ("on", "on"), ("off", "off (one object)")]),
        default: Value::Choice("auto"),
        get: |s| Value::Choice(match s.tiles {
            Tiles::Auto => "auto",
            Tiles::On => "on",
            Tiles::Off => "off",
        }),
        set: |s, v| {
            s.tiles = match choice(v) {
                "on" => Tiles::On,
                "off" => Tiles::Off,
                _ => Tiles::Auto,
            }
        },
        ..BASE
    },
    Setting {
        key: "detail",
        flag: "--detail",
        label: "Scene detail (m)",
        help: "the mesh cell of a tiled scene, in metres (a tile is 64 cells); off follows the scan's density",
        kind: Kind::Float { min: 0.0005, max: 10.0 },
        default: Value::Off,
        can_be_off: true,
        advanced: true,
        get: |s| from_opt(s.detail),
        set: |s, v| s.detail = opt_f32(v),
        ..BASE
    },
    Setting {
        key: "oneLayer",
        flag: "--two-layers",
        label: "One layer per scanned sheet",
        help: "in a tiled scene, a wall or floor scanned from one side comes out of the object prior as two coincident layers; keep the one facing the scan (off keeps both)",
        kind: Kind::Switch,
        default: Value::Bool(true),
        advanced: true,
        get: |s| Value::Bool(s.one_layer),
        set: |s, v| s.one_layer = flag(v),
        ..BASE
    },
    Setting {
        key: "tileRegression",
        flag: "--tile-regression",
        label: "Regression per tile",
        help: "in a tiled scene, tune the kernel regression on each tile's points as on one object's (closer to the points, several times slower); off: each tile meshes the network's field",
        kind: Kind::Switch,
        default: Value::Bool(false),
        nkrr_only: true,
        advanced: true,
        get: |s| Value::Bool(s.tile_regression),
        set: |s, v| s.tile_regression = flag(v),
        ..BASE
    },
    Setting {
        key: "trim",
        flag: "--trim",
        label: "Trim to the scan",
        help: "open the surface where there are no points: drop triangles farther than this many point spacings from them (the cloud's mean, wider where the points are sparser)",
        kind: Kind::Float { min: 0.1, max: 1000.0 },
        default: Value::Off,
        can_be_off: true,
        bare: Some(3.0),
        advanced: true,
        get: |s| from_opt(s.trim),
        set: |s, v| s.trim = opt_f32(v),
        ..BASE
    },
    Setting {
        key: "triangles",
        flag: "--triangles",
        label: "Simplify to triangles",
        help: "simplify the mesh to at most this many triangles by quadric edge collapses (a closed mesh stays closed, a trimmed one keeps its border); off keeps every triangle",
        kind: Kind::Int { min: 4.0, max: 1e9 },
        default: Value::Off,
        can_be_off: true,
        off_flag: Some("--all-triangles"),
        presets: &[(100_000.0, "100k"), (20_000.0, "20k"), (5_000.0, "5k")],
        get: |s| from_opt_usize(s.triangles),
        set: |s, v| s.triangles = opt_usize(v),
        ..BASE
    },
    Setting {
        key: "maxError",
        flag: "--max-error",
        label: "Simplify within",
        help: "simplify as long as the surface moves less than this fraction of the object's size (0.001: a millimetre on a metre); with a triangle count, whichever stops first; off: no error bound",
        kind: Kind::Float { min: 1e-6, max: 1.0 },
        default: Value::Off,
        can_be_off: true,
        presets: &[(0.0005, "0.05 %"), (0.002, "0.2 %"), (0.01, "1 %")],
        advanced: true,
        get: |s| from_opt(s.max_error),
        set: |s, v| s.max_error = opt_f32(v),
        ..BASE
    },
    Setting {
        key: "glb",
        flag: "--glb",
        label: "GLB geometry",
        help: "how the GLB stores the mesh: plain floats (any glTF reader), quantized (KHR_mesh_quantization, about half the size) or meshopt (quantized and EXT_meshopt_compression, about a tenth; three.js, Babylon.js, model-viewer)",
        kind: Kind::Choice(&[("plain", "plain floats"), ("quantized", "quantized"), ("meshopt", "meshopt-compressed")]),
        default: Value::Choice("plain"),
        glb_only: true,
        get: |s| Value::Choice(match s.glb {
            Compression::None => "plain",
            Compression::Quantized => "quantized",
            Compression::Meshopt => "meshopt",
        }),
        set: |s, v| s.glb = match choice(v) {
            "quantized" => Compression::Quantized,
            "meshopt" => Compression::Meshopt,
            _ => Compression::None,
        },
        ..BASE
    },
    Setting {
        key: "fit",
        flag: "--no-fit",
        label: "Fit the mesh to the points",
        help: "move each vertex onto the least-squares plane of its nearest points; off keeps the field's level set as it is (the paper's output)",
        kind: Kind::Switch,
        default: Value::Bool(true),
        get: |s| Value::Bool(s.fit),
        set: |s, v| s.fit = flag(v),
        ..BASE
    },
    Setting {
        key: "fitNoise",
        flag: "--fit-noise",
        label: "Fit follows the noise",
        help: "on a cloud noisier than usual scans, the last fit averages over more points (as many more as the noise's variance is larger); measured better on noisy clouds, not yet the default (docs/results.md was not regenerated with it)",
        kind: Kind::Switch,
        default: Value::Bool(false),
        advanced: true,
        get: |s| Value::Bool(s.fit_noise),
        set: |s, v| s.fit_noise = flag(v),
        ..BASE
    },
    Setting {
        key: "colors",
        flag: "--no-colors",
        label: "Vertex colours",
        help: "colour the mesh's vertices from a coloured cloud (written as COLOR_0)",
        kind: Kind::Switch,
        default: Value::Bool(true),
        advanced: true,
        get: |s| Value::Bool(s.colors),
        set: |s, v| s.colors = flag(v),
        ..BASE
    },
    Setting {
        key: "maxPoints",
        flag: "--max-points",
        label: "Points for the network",
        help: "larger clouds are subsampled uniformly (seeded) for the encoder, which was trained on 500-10k points",
        kind: Kind::Int { min: 1.0, max: 100_000_000.0 },
        default: Value::Num(100_000.0),
        advanced: true,
        get: |s| Value::Num(s.max_points as f64),
        set: |s, v| s.max_points = num(v) as usize,
        ..BASE
    },
    Setting {
        key: "lambda",
        flag: "--lambda",
        label: "Ridge λ",
        help: "ridge parameter of the KRR (the paper does not give it; chosen on the eval clouds, docs/krr.md)",
        kind: Kind::Float { min: 1e-12, max: 1e6 },
        default: Value::Num(1e-5),
        nkrr_only: true,
        advanced: true,
        get: |s| Value::Num(s.lambda),
        set: |s, v| s.lambda = num(v),
        ..BASE
    },
    Setting {
        key: "labelClip",
        flag: "--label-clip",
        label: "Label clip",
        help: "clip the network logits used as targets to [-C, C]; off regresses the raw logits, as the paper does",
        kind: Kind::Float { min: 1e-3, max: 1e6 },
        default: Value::Num(4.0),
        can_be_off: true,
        off_flag: Some("--no-label-clip"),
        nkrr_only: true,
        advanced: true,
        get: |s| from_opt(s.label_clip),
        set: |s, v| s.label_clip = opt_f32(v),
        ..BASE
    },
    Setting {
        key: "knnK",
        flag: "--knn-k",
        label: "Offset neighbour",
        help: "neighbour rank whose distance scales the offsets of the extra training points",
        kind: Kind::Int { min: 1.0, max: 1000.0 },
        default: Value::Num(50.0),
        nkrr_only: true,
        advanced: true,
        get: |s| Value::Num(s.knn_k as f64),
        set: |s, v| s.knn_k = num(v) as usize,
        ..BASE
    },
    Setting {
        key: "nearK",
        flag: "--near-k",
        label: "Near offset neighbour",
        help: "every other extra training point is offset by the distance to this neighbour instead, nearer the surface (chosen on cow, fandisk, suzanne; docs/results.md); off: one scale (the paper)",
        kind: Kind::Int { min: 1.0, max: 1000.0 },
        default: Value::Num(10.0),
        can_be_off: true,
        off_flag: Some("--one-scale"),
        nkrr_only: true,
        advanced: true,
        get: |s| from_opt_usize(s.near_k),
        set: |s, v| s.near_k = opt_usize(v),
        ..BASE
    },
    Setting {
        key: "extraPairs",
        flag: "--extra-pairs",
        label: "Least extra points",
        help: "sparse clouds get several extra training points per input point, up to 16, so that there are at least this many (chosen on cow, fandisk, suzanne; docs/results.md); off: one per point (the paper)",
        kind: Kind::Int { min: 1.0, max: 10_000_000.0 },
        default: Value::Num(4000.0),
        can_be_off: true,
        off_flag: Some("--one-pair-per-point"),
        nkrr_only: true,
        advanced: true,
        get: |s| from_opt_usize(s.extra_pairs),
        set: |s, v| s.extra_pairs = opt_usize(v),
        ..BASE
    },
    Setting {
        key: "across",
        flag: "--across",
        label: "Pairs across the surface",
        help: "two more training points per input point, this many near-offset distances (--near-k) along its PCA normal, labelled inside and outside by the network's ordering of the two and their neighbours' (at least ±1): thin parts the network misses get an inside (chosen on cow, fandisk, suzanne; docs/results.md); off: none (the paper)",
        kind: Kind::Float { min: 0.01, max: 10.0 },
        default: Value::Num(0.5),
        can_be_off: true,
        off_flag: Some("--no-across"),
        nkrr_only: true,
        advanced: true,
        get: |s| from_opt(s.across),
        set: |s, v| s.across = opt_f32(v),
        ..BASE
    },
    Setting {
        key: "tuneTheta",
        flag: "--no-theta",
        label: "Tune length-scales",
        help: "tune the kernel length-scales θ; off is the paper's ablation 'w/o θ'",
        kind: Kind::Switch,
        default: Value::Bool(true),
        nkrr_only: true,
        advanced: true,
        get: |s| Value::Bool(s.tune_theta),
        set: |s, v| s.tune_theta = flag(v),
        ..BASE
    },
    Setting {
        key: "tuneZ",
        flag: "--no-z",
        label: "Tune inducing points",
        help: "tune the inducing points Z; off is the paper's ablation 'w/o Z'",
        kind: Kind::Switch,
        default: Value::Bool(true),
        nkrr_only: true,
        advanced: true,
        get: |s| Value::Bool(s.tune_z),
        set: |s, v| s.tune_z = flag(v),
        ..BASE
    },
    Setting {
        key: "position",
        flag: "--position",
        label: "Position in the kernel",
        help: "the kernel sees each query's position beside the network's features, each coordinate with its own tuned length-scale (beyond the paper)",
        kind: Kind::Switch,
        default: Value::Bool(false),
        nkrr_only: true,
        advanced: true,
        get: |s| Value::Bool(s.position),
        set: |s, v| s.position = flag(v),
        ..BASE
    },
    Setting {
        key: "euclidean",
        flag: "--euclidean",
        label: "Coordinates, not features",
        help: "regress on Fourier-encoded coordinates instead of the network's features (the paper's ablation)",
        kind: Kind::Switch,
        default: Value::Bool(false),
        nkrr_only: true,
        advanced: true,
        get: |s| Value::Bool(s.euclidean),
        set: |s, v| s.euclidean = flag(v),
        ..BASE
    },
    Setting {
        key: "krrBackend",
        flag: "--krr-backend",
        label: "Regression runs on",
        help: "where the KRR objective runs (auto: CPU f64 on software adapters, the GPU otherwise)",
        kind: Kind::Choice(&[("auto", "auto"), ("gpu", "GPU"), ("cpu", "CPU (f64)")]),
        default: Value::Choice("auto"),
        nkrr_only: true,
        advanced: true,
        get: |s| Value::Choice(match s.krr_backend {
            KrrBackend::Auto => "auto",
            KrrBackend::Gpu => "gpu",
            KrrBackend::Cpu => "cpu",
        }),
        set: |s, v| {
            s.krr_backend = match choice(v) {
                "gpu" => KrrBackend::Gpu,
                "cpu" => KrrBackend::Cpu,
                _ => KrrBackend::Auto,
            }
        },
        ..BASE
    },
];

/// The entry with JS/link key `key`.
pub fn by_key(key: &str) -> Option<&'static Setting> {
    TABLE.iter().find(|d| d.key == key)
}

/// The entry with CLI flag `flag`.
pub fn by_flag(flag: &str) -> Option<&'static Setting> {
    TABLE.iter().find(|d| d.flag == flag)
}

impl Setting {
    /// The value of this setting in `s`.
    pub fn get(&self, s: &Settings) -> Value {
        (self.get)(s)
    }

    /// Sets this setting in `s` to `v`, after [`Setting::check`].
    pub fn set(&self, s: &mut Settings, v: Value) -> Result<(), String> {
        let v = self.check(v)?;
        (self.set)(s, v);
        Ok(())
    }

    /// `v` if this setting takes it, else a message that names the setting and its range.
    pub fn check(&self, v: Value) -> Result<Value, String> {
        match (self.kind, v) {
            (_, Value::Off) if self.can_be_off || (self.default == Value::Off && matches!(self.kind, Kind::Choice(_))) => {
                Ok(Value::Off)
            }
            (Kind::Int { .. } | Kind::Float { .. }, Value::Num(0.0)) if self.can_be_off => Ok(Value::Off),
            (Kind::Int { min, max }, Value::Num(x)) if x.is_finite() && x.fract() == 0.0 && (min..=max).contains(&x) => {
                Ok(v)
            }
            (Kind::Float { min, max }, Value::Num(x)) if x.is_finite() && (min..=max).contains(&x) => Ok(v),
            (Kind::Choice(_), Value::Choice("")) if self.default == Value::Off => Ok(Value::Off),
            (Kind::Choice(choices), Value::Choice(c)) => {
                choices.iter().find(|(value, _)| *value == c).map(|(value, _)| Value::Choice(value)).ok_or_else(|| self.range_error(format!("'{c}'")))
            }
            (Kind::Switch, Value::Bool(_)) => Ok(v),
            _ => Err(self.range_error(value_text(v))),
        }
    }

    /// Reads `text` (a CLI argument, a share link's parameter, a form field) as a value of this
    /// setting.
    /// The one rule for text, wherever it comes from (the page's share links are read by this
    /// too, through the wasm module): switches take `1 true on yes` and `0 false off no` in any
    /// letter case; a number that can be off is off at `0`, `off` or empty.
    pub fn parse(&self, text: &str) -> Result<Value, String> {
        let text = text.trim();
        match self.kind {
            Kind::Int { .. } | Kind::Float { .. } => {
                if self.can_be_off && (text.is_empty() || text.eq_ignore_ascii_case("off")) {
                    return Ok(Value::Off);
                }
                let x: f64 = text.parse().map_err(|_| self.range_error(format!("'{text}'")))?;
                self.check(Value::Num(x))
            }
            Kind::Choice(choices) => {
                let c = choices.iter().find(|(value, _)| *value == text).map(|(value, _)| *value);
                c.map(Value::Choice).ok_or_else(|| self.range_error(format!("'{text}'"))).and_then(|v| self.check(v))
            }
            Kind::Switch => match text.to_ascii_lowercase().as_str() {
                // A bare share-link parameter (`?euclidean`) means on.
                "" | "true" | "1" | "on" | "yes" => Ok(Value::Bool(true)),
                "false" | "0" | "off" | "no" => Ok(Value::Bool(false)),
                _ => Err(self.range_error(format!("'{text}'"))),
            },
        }
    }

    /// What the setting takes, in words: "a whole number from 1 to 5000", "one of nkrr, network".
    pub fn range(&self) -> String {
        let off = if self.can_be_off { ", or 0 for off" } else { "" };
        match self.kind {
            Kind::Int { min, max } => format!("a whole number from {min} to {max}{off}"),
            Kind::Float { min, max } => format!("a number from {min} to {max}{off}"),
            Kind::Choice(choices) => {
                let names: Vec<&str> = choices.iter().map(|(v, _)| *v).filter(|v| !v.is_empty()).collect();
                let off = if self.default == Value::Off { ", or empty for none" } else { "" };
                format!("one of {}{off}", names.join(", "))
            }
            Kind::Switch => "true or false".to_string(),
        }
    }

    fn range_error(&self, got: impl std::fmt::Display) -> String {
        format!("{} must be {}, not {got}", self.key, self.range())
    }

    /// The default as text: "500", "nkrr", "off", "true".
    pub fn default_text(&self) -> String {
        value_text(self.default)
    }

    /// The usage text's line for this setting: flag, value, help, range and default.
    pub fn usage_line(&self) -> String {
        let head = match self.kind {
            Kind::Switch => self.flag.to_string(),
            Kind::Choice(choices) => {
                let names: Vec<&str> = choices.iter().map(|(v, _)| *v).filter(|v| !v.is_empty()).collect();
                format!("{} {}", self.flag, names.join("|"))
            }
            Kind::Int { .. } => format!("{} N", self.flag),
            Kind::Float { .. } if self.bare.is_some() => format!("{} [F]", self.flag),
            Kind::Float { .. } => format!("{} F", self.flag),
        };
        let mut extra = Vec::new();
        if let Some(off) = self.off_flag {
            extra.push(format!("{off} turns it off"));
        }
        for (alias, v) in self.aliases {
            extra.push(format!("{alias} means {} {v}", self.flag));
        }
        if let Some(b) = self.bare {
            extra.push(format!("alone: {b}"));
        }
        let range = match self.kind {
            Kind::Int { min, max } | Kind::Float { min, max } => format!(" ({min}..={max})"),
            _ => String::new(),
        };
        let extra = if extra.is_empty() { String::new() } else { format!("; {}", extra.join("; ")) };
        let (turns, default) = match (self.kind, self.default) {
            (Kind::Switch, Value::Bool(true)) => ("turns off: ", String::new()),
            (Kind::Switch, _) => ("turns on: ", String::new()),
            _ => ("", format!("  [{}]", self.default_text())),
        };
        format!("        {head:<26} {turns}{}{range}{extra}{default}", self.help)
    }
}

/// A setting asked for (a value other than its default) that the run will not use: a
/// regression setting with the network alone, a GLB setting for another output. [`unused`] is
/// the one rule; the CLI warns of each before any work, the page and the JS API in the run's
/// warnings.
#[derive(Clone, Copy)]
pub struct Unused {
    pub setting: &'static Setting,
    pub value: Value,
    /// What it needs that the run does not have.
    pub needs: &'static str,
}

impl Unused {
    /// In the CLI's words: "--m 1000 has no effect and is ignored: it needs the nkrr method
    /// (--method nkrr)".
    pub fn cli(&self) -> String {
        let value = match self.setting.kind {
            Kind::Switch => String::new(),
            _ => format!(" {}", value_text(self.value)),
        };
        format!("{}{value} has no effect and is ignored: it needs {}", self.setting.flag, self.needs)
    }

    /// In the page's words, by the form's label.
    pub fn page(&self) -> String {
        format!("“{}” ({}) has no effect and is ignored: it needs {}", self.setting.label, value_text(self.value), self.needs)
    }
}

/// The settings of `s` that differ from their defaults but do not apply to its method or to
/// the `output` format (None: every format is offered, as on the page).
pub fn unused(s: &Settings, output: Option<crate::io::mesh_out::MeshFormat>) -> Vec<Unused> {
    use crate::io::mesh_out::MeshFormat;
    TABLE
        .iter()
        .filter_map(|def| {
            let value = def.get(s);
            if value == def.default {
                return None;
            }
            let needs = if def.nkrr_only && s.method != Method::Nkrr {
                "the nkrr method (--method nkrr)"
            } else if def.glb_only && output.is_some_and(|f| f != MeshFormat::Glb) {
                "a .glb output"
            } else {
                return None;
            };
            Some(Unused { setting: def, value, needs })
        })
        .collect()
}

/// A value as text (the form the CLI and links take).
pub fn value_text(v: Value) -> String {
    match v {
        Value::Off => "off".to_string(),
        Value::Bool(b) => b.to_string(),
        Value::Num(x) => format!("{x}"),
        Value::Choice(c) => c.to_string(),
    }
}

/// Applies command-line flag `arg` to `s`, taking its value from `rest` when it has one;
/// returns how many of `rest` it used, or None when `arg` is not a setting's flag.
pub fn apply_flag(s: &mut Settings, arg: &str, rest: &[String]) -> Option<Result<usize, String>> {
    for def in TABLE {
        if def.off_flag == Some(arg) {
            return Some(def.set(s, Value::Off).map(|_| 0));
        }
        if let Some((_, v)) = def.aliases.iter().find(|(a, _)| *a == arg) {
            return Some(def.set(s, Value::Num(*v)).map(|_| 0));
        }
        if def.flag != arg {
            continue;
        }
        return Some(match (def.kind, def.bare) {
            (Kind::Switch, _) => {
                let on = def.default != Value::Bool(true);
                def.set(s, Value::Bool(on)).map(|_| 0)
            }
            // The value is optional: take the next argument only when it is a number.
            (_, Some(bare)) => match rest.first().and_then(|t| t.parse::<f64>().ok()) {
                Some(x) => def.set(s, Value::Num(x)).map(|_| 1).map_err(|e| format!("{arg}: {e}")),
                None => def.set(s, Value::Num(bare)).map(|_| 0),
            },
            _ => match rest.first() {
                None => Err(format!("{arg} needs a value ({})", def.range())),
                Some(t) => def.parse(t).and_then(|v| def.set(s, v)).map(|_| 1).map_err(|e| format!("{arg}: {e}")),
            },
        });
    }
    None
}

/// The usage text's block of reconstruction options, one line per setting.
pub fn usage() -> String {
    TABLE.iter().map(|d| d.usage_line() + "\n").collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_field_has_one_entry() {
        // Changing one entry's value changes exactly that entry's reading of the struct.
        let base = Settings::default();
        for def in TABLE {
            assert_eq!(def.get(&base), def.default, "{}", def.key);
            let other = match def.kind {
                Kind::Int { min, max } | Kind::Float { min, max } => {
                    Value::Num(if def.default == Value::Num(max) { min } else { max })
                }
                Kind::Choice(c) => {
                    Value::Choice(c.iter().map(|(v, _)| *v).find(|v| !v.is_empty() && Value::Choice(v) != def.default).unwrap())
                }
                Kind::Switch => Value::Bool(def.default != Value::Bool(true)),
            };
            let mut s = base.clone();
            def.set(&mut s, other).unwrap();
            assert_eq!(def.get(&s), other, "{}", def.key);
            for d in TABLE.iter().filter(|d| d.key != def.key) {
                assert_eq!(d.get(&s), d.get(&base), "setting {} also changed {}", def.key, d.key);
            }
        }
    }

    #[test]
    fn keys_and_flags_are_unique() {
        let mut seen = std::collections::HashSet::new();
        for d in TABLE {
            assert!(seen.insert(d.key), "{}", d.key);
            for f in [Some(d.flag), d.off_flag].into_iter().flatten().chain(d.aliases.iter().map(|a| a.0)) {
                assert!(f.starts_with("--") && seen.insert(f), "{f}");
            }
        }
    }

    #[test]
    fn values_out_of_range_are_refused_with_the_range() {
        let m = by_key("m").unwrap();
        assert_eq!(m.parse("0"), Err("m must be a whole number from 1 to 5000, not 0".into()));
        assert_eq!(m.parse("2.5"), Err("m must be a whole number from 1 to 5000, not 2.5".into()));
        assert_eq!(m.parse("lots"), Err("m must be a whole number from 1 to 5000, not 'lots'".into()));
        assert_eq!(m.parse("1000"), Ok(Value::Num(1000.0)));
        assert!(by_key("lambda").unwrap().parse("0").is_err());
        assert!(by_key("lambda").unwrap().parse("nan").is_err());
        assert_eq!(by_key("labelClip").unwrap().parse("0"), Ok(Value::Off));
        assert_eq!(by_key("units").unwrap().parse(""), Ok(Value::Off));
        assert!(by_key("units").unwrap().parse("furlong").is_err());
        assert!(by_key("method").unwrap().parse("").is_err());
        assert_eq!(by_key("euclidean").unwrap().parse(""), Ok(Value::Bool(true)));
        // One rule for the CLI, the JS API and share links: letter case and "off".
        assert_eq!(by_key("euclidean").unwrap().parse("OFF"), Ok(Value::Bool(false)));
        assert_eq!(by_key("euclidean").unwrap().parse("Yes"), Ok(Value::Bool(true)));
        assert_eq!(by_key("labelClip").unwrap().parse("Off"), Ok(Value::Off));
        assert!(by_key("m").unwrap().parse("off").is_err());
    }

    #[test]
    fn flags_apply() {
        let mut s = Settings::default();
        let args = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        assert_eq!(apply_flag(&mut s, "--m", &args(&["800"])), Some(Ok(1)));
        assert_eq!(apply_flag(&mut s, "--trim", &args(&["--m"])), Some(Ok(0)));
        assert_eq!(s.trim, Some(3.0));
        assert_eq!(apply_flag(&mut s, "--trim", &args(&["2"])), Some(Ok(1)));
        assert_eq!(apply_flag(&mut s, "--no-label-clip", &[]), Some(Ok(0)));
        assert_eq!(apply_flag(&mut s, "--no-tune", &[]), Some(Ok(0)));
        assert_eq!(apply_flag(&mut s, "--no-colors", &[]), Some(Ok(0)));
        assert_eq!(apply_flag(&mut s, "--euclidean", &[]), Some(Ok(0)));
        assert_eq!((s.m, s.trim, s.label_clip, s.steps, s.colors, s.euclidean), (800, Some(2.0), None, 0, false, true));
        assert!(matches!(apply_flag(&mut s, "--resolution", &args(&["8"])), Some(Err(_))));
        assert!(matches!(apply_flag(&mut s, "--m", &[]), Some(Err(_))));
        assert_eq!(apply_flag(&mut s, "--output", &[]), None);
    }
}

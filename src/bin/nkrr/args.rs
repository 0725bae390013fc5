//! Every command and every flag of the command line, in one table each ([`COMMANDS`], [`FLAGS`];
//! the reconstruction options are the settings table's, `nkrr::settings::TABLE`): the parser
//! ([`parse`]) and the usage text ([`usage`]) are both made from them, so a flag cannot be
//! accepted without being listed, or listed with another meaning. (In the spirit of ripgrep's one
//! list of flags.)

use nkrr::settings::Settings;

/// A command: its operands and what it does, for the usage text.
pub struct Command {
    pub name: &'static str,
    /// Its operands as the usage shows them ("CLOUD", "DIR").
    pub operands: &'static str,
    pub help: &'static str,
    /// Whether it takes the reconstruction options (the settings table's flags).
    pub settings: bool,
}

/// A command's own flag (not a reconstruction setting).
pub struct Flag {
    /// The commands that take it.
    pub commands: &'static [&'static str],
    /// Its names; the first is the one [`Parsed::value`] and [`Parsed::has`] ask for.
    pub names: &'static [&'static str],
    /// The value's placeholder (None: a switch).
    pub value: Option<&'static str>,
    /// What it does.
    pub help: &'static str,
    /// The value when the flag is not given: what [`Parsed::value`] returns then, and what the
    /// usage shows in brackets (the one place for it).
    pub default: Option<&'static str>,
    /// When set, the flag is refused with this reason: a setting that another flag of the
    /// command replaces (`eval --method`: see `--methods`).
    pub refused: Option<&'static str>,
}

/// Every command, in the order the usage lists them.
pub static COMMANDS: &[Command] = &[
    Command {
        name: "info",
        operands: "CLOUD",
        help: "point count, bounds, a units guess, attributes, warnings, and the memory each stage needs on this machine's GPU (for the options)",
        settings: true,
    },
    Command {
        name: "reconstruct",
        operands: "CLOUD -o OUT",
        help: "a watertight mesh of the cloud; the output's extension picks the format",
        settings: true,
    },
    Command {
        name: "metrics",
        operands: "GT.obj RECON.glb|RECON.obj [RECON ...]",
        help: "one JSON line per reconstruction: cd1x100, fscore, nc, iou (null unless GT is watertight), watertight (the reconstruction's), by the protocol of the eval data (see nkrr::eval)",
        settings: false,
    },
    Command {
        name: "eval",
        operands: "DIR",
        help: "reconstruct every DIR/NAME-SIZE.ply with each method, score it against DIR/NAME.obj; writes PREFIX.md and PREFIX.json",
        settings: true,
    },
    Command {
        name: "bench",
        operands: "",
        help: "per-stage times on a synthetic noisy torus (adapter printed); the method is nkrr with 10 steps unless set",
        settings: true,
    },
    Command { name: "gpu", operands: "", help: "the GPU adapter wgpu finds here and its limits", settings: false },
];

const NOT_FOR_EVAL: &str = "is not an eval option (see --methods, --out)";

/// Every flag of a command's own.
pub static FLAGS: &[Flag] = &[
    Flag {
        commands: &["reconstruct"],
        names: &["-o", "--output"],
        value: Some("OUT.glb|.ply|.obj|.stl"),
        help: "the mesh file to write (never the input)",
        default: None,
        refused: None,
    },
    Flag {
        commands: &["reconstruct", "eval"],
        names: &["--weights"],
        value: Some("PRIOR.safetensors"),
        help: "a network prior in the built-in one's format (one exported by training/export.py) instead of the built-in one",
        default: None,
        refused: None,
    },
    Flag {
        commands: &["metrics"],
        names: &["--seed"],
        value: Some("N"),
        help: "another seed of the protocol's samples, to see the sampling noise (nkrr::eval::Protocol's otherwise)",
        default: None,
        refused: None,
    },
    Flag {
        commands: &["eval"],
        names: &["--sizes"],
        value: Some("3k,10k"),
        help: "the cloud sizes: DIR/NAME-SIZE.ply for each",
        default: Some("3k,10k"),
        refused: None,
    },
    Flag {
        commands: &["eval"],
        names: &["--methods"],
        value: Some("network,nkrr"),
        help: "the methods to compare (see METHODS below)",
        default: Some("network,nkrr"),
        refused: None,
    },
    Flag { commands: &["eval"], names: &["--shapes"], value: Some("A,B"), help: "only these NAMEs (all when not given)", default: None, refused: None },
    Flag { commands: &["eval"], names: &["--out"], value: Some("PREFIX"), help: "where the reports go", default: Some("eval"), refused: None },
    Flag {
        commands: &["eval"],
        names: &["--keep-meshes"],
        value: None,
        help: "also write PREFIX-NAME-SIZE-METHOD.glb",
        default: None,
        refused: None,
    },
    Flag { commands: &["eval"], names: &["--method"], value: None, help: "", default: None, refused: Some(NOT_FOR_EVAL) },
    Flag { commands: &["eval"], names: &["-o", "--output"], value: None, help: "", default: None, refused: Some(NOT_FOR_EVAL) },
    Flag {
        commands: &["bench"],
        names: &["--sizes"],
        value: Some("3000,10000,50000"),
        help: "cloud sizes of the torus",
        default: Some("3000,10000,50000"),
        refused: None,
    },
    Flag {
        commands: &["bench"],
        names: &["--ms"],
        value: Some("500,1000"),
        help: "inducing points, each within --m's range",
        default: Some("500,1000"),
        refused: None,
    },
];

/// A command line read by the tables: operands, the command's own flags, the settings.
#[derive(Debug)]
pub struct Parsed {
    command: String,
    pub operands: Vec<String>,
    values: Vec<(&'static str, String)>,
    pub settings: Settings,
}

impl Parsed {
    /// The last value given for the flag named `name` (its first name in [`FLAGS`]), else its
    /// default.
    pub fn value(&self, name: &str) -> Option<&str> {
        let given = self.values.iter().rev().find(|(n, _)| *n == name).map(|(_, v)| v.as_str());
        given.or_else(|| flag(&self.command, name).and_then(|f| f.default))
    }

    /// Whether the switch or flag named `name` was given.
    pub fn has(&self, name: &str) -> bool {
        self.values.iter().any(|(n, _)| *n == name)
    }
}

/// The flag of `command` whose first name is `name`.
fn flag(command: &str, name: &str) -> Option<&'static Flag> {
    FLAGS.iter().find(|f| f.commands.contains(&command) && f.names[0] == name)
}

/// Reads `args` (after the command's name) for `command`, starting from `settings`. An error is
/// a usage message (the caller adds the usage text): what is wrong, with the flag's name.
pub fn parse(command: &str, args: &[String], mut settings: Settings) -> Result<Parsed, String> {
    let takes_settings = COMMANDS.iter().any(|c| c.name == command && c.settings);
    let mut operands = Vec::new();
    let mut values = Vec::new();
    let mut i = 0;
    while i < args.len() {
        let a = args[i].as_str();
        i += 1;
        if let Some(f) = FLAGS.iter().find(|f| f.commands.contains(&command) && f.names.contains(&a)) {
            if let Some(why) = f.refused {
                return Err(format!("{command}: {a} {why}"));
            }
            let value = match f.value {
                None => String::new(),
                Some(_) => {
                    let v = args.get(i).ok_or_else(|| format!("{a} needs a value"))?;
                    i += 1;
                    v.clone()
                }
            };
            values.push((f.names[0], value));
            continue;
        }
        if takes_settings {
            match nkrr::settings::apply_flag(&mut settings, a, &args[i..(i + 1).min(args.len())]) {
                Some(Ok(used)) => {
                    i += used;
                    continue;
                }
                Some(Err(e)) => return Err(e),
                None => {}
            }
        }
        if a.starts_with('-') && a.len() > 1 {
            return Err(format!("{command}: unknown option '{a}'"));
        }
        operands.push(a.to_string());
    }
    Ok(Parsed { command: command.to_string(), operands, values, settings })
}

/// `text` broken at spaces into lines of at most `width` characters, every line after the first
/// indented by `indent` spaces.
pub fn wrapped(text: &str, indent: usize, width: usize) -> String {
    let mut lines = vec![String::new()];
    for word in text.split(' ') {
        let line = lines.last_mut().expect("one line at least");
        if !line.is_empty() && indent + line.len() + word.len() + 1 > width {
            lines.push(String::new());
        }
        let line = lines.last_mut().expect("one line at least");
        if !line.is_empty() {
            line.push(' ');
        }
        line.push_str(word);
    }
    lines.join(&format!("\n{}", " ".repeat(indent)))
}

/// The usage text, made from [`COMMANDS`], [`FLAGS`], the settings table and the eval methods.
pub fn usage() -> String {
    let mut out = String::from(
        "nkrr — surface reconstruction from raw point clouds\n\nUSAGE:\n    CLOUD is a point cloud in any of these formats, recognised by its content: PLY, text\n    (XYZ/PTS/CSV/TXT: x y z per line, optional intensity, r g b and nx ny nz), LAS/LAZ 1.0-1.4,\n    E57 (every scan, with its pose). Normals are never needed.\n\n",
    );
    for c in COMMANDS {
        let own: Vec<&Flag> = FLAGS.iter().filter(|f| f.commands.contains(&c.name) && f.refused.is_none()).collect();
        let mut synopsis = format!("nkrr {}", c.name);
        if !c.operands.is_empty() {
            synopsis += &format!(" {}", c.operands);
        }
        if !own.is_empty() || c.settings {
            synopsis += " [OPTIONS]";
        }
        out += &format!("    {synopsis}\n        {}\n", wrapped(c.help, 8, 96));
        for f in own {
            let head = match f.value {
                Some(v) => format!("{} {v}", f.names.join(", ")),
                None => f.names.join(", "),
            };
            // A long head puts its help on the next line, in the help column.
            let gap = if head.len() > 26 { format!("\n{}", " ".repeat(35)) } else { format!("{:1$}", "", 27 - head.len()) };
            let help = match f.default {
                Some(d) => format!("{}  [{d}]", f.help),
                None => f.help.to_string(),
            };
            out += &format!("        {head}{gap}{}\n", wrapped(&help, 35, 96));
        }
        if c.settings {
            let refused: Vec<&str> = FLAGS.iter().filter(|f| f.commands.contains(&c.name) && f.refused.is_some()).flat_map(|f| f.names.iter().copied()).collect();
            let but = if refused.is_empty() { String::new() } else { format!(" except {}", refused.join(", ")) };
            out += &format!("        and the reconstruction options{but} (below)\n");
        }
        if c.name == "eval" {
            out += &format!("        METHODS: {}\n", wrapped(&nkrr::eval::variant_names(), 17, 96));
        }
        out.push('\n');
    }
    out += "    nkrr --help | --version\n\nRECONSTRUCTION OPTIONS (info, reconstruct, eval, bench):\n";
    out += &nkrr::settings::usage();
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_flag_is_listed_and_unique_per_command() {
        let text = usage();
        for c in COMMANDS {
            let mut seen = std::collections::HashSet::new();
            for f in FLAGS.iter().filter(|f| f.commands.contains(&c.name)) {
                for n in f.names {
                    assert!(seen.insert(*n), "{} {n} twice", c.name);
                    // Its own flags must not shadow a setting's.
                    assert!(nkrr::settings::TABLE.iter().all(|d| d.flag != *n) || f.refused.is_some(), "{n}");
                }
                if f.refused.is_none() {
                    assert!(text.contains(f.names[0]), "{} {} not in the usage", c.name, f.names[0]);
                }
            }
            assert!(text.contains(&format!("nkrr {}", c.name)), "{}", c.name);
        }
        for d in nkrr::settings::TABLE {
            assert!(text.contains(d.flag), "{}", d.flag);
        }
    }

    #[test]
    fn parsing_follows_the_tables() {
        let args = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        let p = parse("reconstruct", &args(&["in.ply", "-o", "out.glb", "--m", "800", "--trim"]), Settings::default()).unwrap();
        assert_eq!(p.operands, ["in.ply"]);
        assert_eq!(p.value("-o"), Some("out.glb"));
        assert_eq!((p.settings.m, p.settings.trim), (800, Some(3.0)));
        assert!(parse("reconstruct", &args(&["-o"]), Settings::default()).unwrap_err().contains("-o needs a value"));
        assert!(parse("metrics", &args(&["--m", "5"]), Settings::default()).unwrap_err().contains("unknown option '--m'"));
        assert!(parse("eval", &args(&["d", "--method", "nkrr"]), Settings::default()).unwrap_err().contains("not an eval option"));
        let p = parse("eval", &args(&["d", "--keep-meshes", "--sizes", "3k"]), Settings::default()).unwrap();
        assert!(p.has("--keep-meshes") && p.value("--sizes") == Some("3k"));
        // Not given: the table's default, which the usage shows.
        assert_eq!((p.value("--out"), p.value("--shapes"), p.has("--out")), (Some("eval"), None, false));
        assert!(usage().contains("where the reports go  [eval]"));
    }
}

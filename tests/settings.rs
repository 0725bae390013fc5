//! Every setting is defined once (`src/settings.rs`): the CLI's usage and parsing offer exactly
//! the table's settings, defaults and ranges. (The page's form, share links and the JS API are
//! checked against the same table in `tests/browser/settings.test.mjs`.)

use std::process::Command;

use nkrr::settings::{self, Kind, Settings, Value, TABLE};

fn nkrr(args: &[&str]) -> (i32, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_nkrr")).args(args).output().expect("run nkrr");
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn the_usage_lists_every_setting_with_its_default_and_range() {
    let (code, usage, _) = nkrr(&["--help"]);
    assert_eq!(code, 0);
    for def in TABLE {
        let line = usage
            .lines()
            .find(|l| l.trim_start().starts_with(&format!("{} ", def.flag)) || l.trim() == def.flag)
            .unwrap_or_else(|| panic!("{} is not in the usage:\n{usage}", def.flag));
        if !matches!(def.kind, Kind::Switch) {
            assert!(line.ends_with(&format!("[{}]", def.default_text())), "{}: {line}", def.key);
        }
        if let Kind::Int { min, max } | Kind::Float { min, max } = def.kind {
            assert!(line.contains(&format!("({min}..={max})")), "{}: {line}", def.key);
        }
        if let Kind::Choice(choices) = def.kind {
            for (value, _) in choices {
                assert!(line.contains(value), "{}: {value} missing in {line}", def.key);
            }
        }
        for flag in def.off_flag.into_iter().chain(def.aliases.iter().map(|a| a.0)) {
            assert!(line.contains(flag), "{}: {flag} missing in {line}", def.key);
        }
    }
    // Nothing else in the reconstruction options looks like one with its own default (the
    // commands' own flags come from their table, src/bin/nkrr/args.rs, listed under each command).
    let options = usage.split("RECONSTRUCTION OPTIONS").nth(1).expect("the usage has the reconstruction options");
    let flags: Vec<&str> = options
        .lines()
        .filter(|l| l.starts_with("        --"))
        .map(|l| l.split_whitespace().next().unwrap())
        .collect();
    assert_eq!(flags.len(), TABLE.len());
    for f in flags {
        assert!(settings::by_flag(f).is_some(), "{f} is in the usage but not in the settings table");
    }
}

#[test]
fn the_cli_refuses_each_setting_out_of_range_with_the_tables_words() {
    for def in TABLE {
        let bad = match def.kind {
            Kind::Int { max, .. } | Kind::Float { max, .. } => format!("{}", max * 2.0 + 1.0),
            Kind::Choice(_) => "bogus".to_string(),
            Kind::Switch => continue,
        };
        // `info` parses the options and stops there: no GPU work for a refused value.
        let (code, _, err) = nkrr(&["info", "/nonexistent.ply", def.flag, &bad]);
        assert_eq!(code, 2, "{} {bad}: {err}", def.flag);
        assert!(err.contains(&format!("{}: {} must be {}, not", def.flag, def.key, def.range())), "{}: {err}", def.flag);
    }
}

#[test]
fn defaults_come_from_the_table() {
    let s = Settings::default();
    for def in TABLE {
        assert_eq!(def.get(&s), def.default, "{}", def.key);
    }
    // The paper's values, where it has them; its tuning (100 Adam steps at lr 0.1 on all pairs)
    // stays reachable as settings (--steps 100 --lr 0.1 --all-pairs) beside the faster default
    // that gives the same meshes (docs/speed.md).
    assert_eq!(s.m, 500);
    assert_eq!((s.steps, s.lr, s.tune_pairs), (30, 0.3, Some(4000)));
    let paper = [("steps", 100.0), ("lr", 0.1)];
    for (key, v) in paper {
        assert_eq!(settings::by_key(key).unwrap().check(Value::Num(v)), Ok(Value::Num(v)), "{key}");
    }
    let pairs = settings::by_key("tunePairs").unwrap();
    assert_eq!((pairs.off_flag, pairs.check(Value::Off)), (Some("--all-pairs"), Ok(Value::Off)));
    assert_eq!(settings::by_key("labelClip").unwrap().default, Value::Num(4.0));
}

/// The eval variants are one list: each resolves, the error names every one, and `nkrr-m<N>`
/// goes through the settings table's range (it once took any N).
#[test]
fn eval_variants_are_one_list_and_m_keeps_its_range() {
    use nkrr::eval::{variant_names, variant_settings, VARIANTS};
    let base = nkrr::settings::Settings::default();
    for (name, _) in VARIANTS {
        assert!(variant_settings(name, &base).is_ok(), "{name}");
    }
    let e = variant_settings("nkrr-bogus", &base).unwrap_err();
    for (name, _) in VARIANTS {
        assert!(e.contains(name), "{name}: {e}");
    }
    assert!(variant_names().ends_with("nkrr-m<N> (e.g. nkrr-m1000)"));
    assert_eq!(variant_settings("nkrr-m1000", &base).unwrap().m, 1000);
    for bad in ["nkrr-m0", "nkrr-m5001", "nkrr-m2.5"] {
        let e = variant_settings(bad, &base).unwrap_err();
        assert!(e.contains("from 1 to 5000"), "{bad}: {e}");
    }
}

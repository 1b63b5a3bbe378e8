//! Unit tests of `cli::args`.

use super::super::range::Range;
use super::*;

fn parse(args: &[&str]) -> Cli {
    Cli::try_parse_from(std::iter::once("stablesurf").chain(args.iter().copied()))
        .unwrap_or_else(|e| panic!("{args:?}: {e}"))
}

#[test]
fn definitions_are_consistent() {
    use clap::CommandFactory;
    Cli::command().debug_assert();
}

#[test]
fn run_without_input_uses_defaults() {
    let CommandArgs::Run(r) = parse(&["run", "-o", "out"]).command else {
        panic!()
    };
    assert!(r.input.is_empty());
    assert!(!r.batch);
    assert_eq!(r.fit.degree, 8);
    assert_eq!(r.fit.kappa.value, fit::Kappa::Auto);
    assert_eq!(r.mesh.depth, None);
    assert_eq!(
        r.formats,
        [
            FormatArg::Glb,
            FormatArg::Ply,
            FormatArg::Exr,
            FormatArg::Png,
            FormatArg::Json
        ]
    );
}

#[test]
fn batch_takes_several_inputs() {
    let CommandArgs::Run(r) = parse(&["run", "a.ply", "b.obj", "--batch", "-o", "out"]).command
    else {
        panic!()
    };
    assert!(r.batch);
    assert_eq!(r.input, [PathBuf::from("a.ply"), PathBuf::from("b.obj")]);
}

#[test]
fn target_triangles_parses_on_run_and_mesh_and_refuses_zero() {
    let CommandArgs::Run(r) = parse(&["run", "-o", "out", "--target-triangles", "20000"]).command
    else {
        panic!()
    };
    assert_eq!(r.mesh.target_triangles, Some(20000));
    let CommandArgs::Mesh(m) =
        parse(&["mesh", "m.json", "-o", "x.ply", "--target-triangles", "4"]).command
    else {
        panic!()
    };
    assert_eq!(m.mesh.target_triangles, Some(4));
    for bad in ["0", "-5", "1.5", "2000000000"] {
        let e = Cli::try_parse_from([
            "stablesurf",
            "mesh",
            "m.json",
            "-o",
            "x.ply",
            "--target-triangles",
            bad,
        ])
        .unwrap_err();
        assert_eq!(e.exit_code(), 2, "{bad}");
        assert!(
            e.to_string()
                .contains("--target-triangles takes a whole number from 1 to 1e9"),
            "{e}"
        );
    }
}

#[test]
fn run_flags_parse() {
    let cli = parse(&[
        "run",
        "scan.ply",
        "-o",
        "out",
        "--degree",
        "8",
        "--kappa",
        "1e-3",
        "--epsilon",
        "0.01",
        "--method",
        "3l",
        "--depth",
        "7",
        "--formats",
        "glb,gltf",
        "--cache-dir",
        "c",
        "--no-cache",
        "--normals",
        "pca",
        "--kappa-rule",
        "paper",
        "--keep",
        "data",
        "--up",
        "z",
        "--json",
        "-v",
        "-v",
        "-j",
        "1",
    ]);
    assert_eq!(cli.verbose, 2);
    assert_eq!(cli.threads, Some(1));
    let CommandArgs::Run(r) = cli.command else {
        panic!()
    };
    assert_eq!(r.fit.degree, 8);
    assert_eq!(r.fit.kappa.value, fit::Kappa::Fixed(1e-3));
    assert_eq!(r.fit.epsilon, 0.01);
    assert_eq!(r.fit.method, MethodArg::ThreeL);
    assert_eq!(r.fit.kappa_rule, KappaRuleArg::Paper);
    assert_eq!(r.mesh.depth, Some(7));
    assert_eq!(r.keep, Some(KeepArg::Data));
    assert_eq!(r.frame.up, Some(UpArg::Z));
    assert_eq!(r.normals.source, SourceArg::Pca);
    assert!(r.cache.no_cache && r.json);
    assert_eq!(r.cache.cache_dir, Some(PathBuf::from("c")));
    assert_eq!(r.formats, [FormatArg::Glb, FormatArg::Gltf]);
}

#[test]
fn mesh_bounds_take_six_numbers() {
    let CommandArgs::Mesh(m) = parse(&[
        "mesh",
        "m.json",
        "-o",
        "x.ply",
        "--bounds",
        "-1,-1,-1,1,1,1",
    ])
    .command
    else {
        panic!()
    };
    assert_eq!(m.bounds, Some([-1.0, -1.0, -1.0, 1.0, 1.0, 1.0]));
    for bad in ["1,2", "0,0,0,1,1,x", "0,0,0,0,1,1", "0,0,0,1,1,inf"] {
        let r = Cli::try_parse_from(["stablesurf", "mesh", "m", "-o", "x", "--bounds", bad]);
        assert_eq!(r.unwrap_err().exit_code(), 2, "{bad}");
    }
}

#[test]
fn slices_and_info_and_cache_parse() {
    let CommandArgs::Slices(s) = parse(&[
        "slices",
        "m.json",
        "-o",
        "d",
        "--axis",
        "x",
        "--count",
        "4",
        "--resolution",
        "64",
        "--distance",
        "taubin",
    ])
    .command
    else {
        panic!()
    };
    assert_eq!(
        (s.axis, s.count, s.resolution, s.distance),
        (AxisArg::X, 4, 64, Some(DistanceArg::Taubin))
    );
    let CommandArgs::Info(i) = parse(&["info", "f.ply", "--json"]).command else {
        panic!()
    };
    assert!(i.json);
    let CommandArgs::Cache(c) = parse(&["cache", "clear", "--cache-dir", "x"]).command else {
        panic!()
    };
    assert!(matches!(c.action, CacheAction::Clear { older_than: None }));
    let CommandArgs::Normals(n) =
        parse(&["normals", "a.xyz", "-o", "n.ply", "--mesh", "c.ply"]).command
    else {
        panic!()
    };
    assert_eq!(n.mesh, Some(PathBuf::from("c.ply")));
}

/// Each ranged flag's help prints its constant's range, and its parser takes both ends and
/// refuses the values just outside them.
#[test]
fn ranged_flags_print_and_check_the_same_constant() {
    use clap::CommandFactory;
    let cli = Cli::command();
    let cases: [(&str, &str, Range); 16] = [
        ("run", "threads", THREADS),
        ("run", "trim", TRIM),
        ("run", "degree", DEGREE),
        ("run", "kappa", KAPPA),
        ("run", "epsilon", EPSILON),
        ("run", "local_degree", LOCAL_DEGREE),
        ("run", "tolerance", TOLERANCE),
        ("run", "smooth", SMOOTH),
        ("run", "depth", DEPTH),
        ("run", "slice_count", SLICE_COUNT),
        ("run", "slice_resolution", SLICE_RESOLUTION),
        ("run", "voxel_size", VOXEL_SIZE),
        ("slices", "count", COUNT),
        ("slices", "resolution", RESOLUTION),
        ("slices", "depth", DEPTH),
        ("render", "size", SIZE),
    ];
    for (sub, id, range) in cases {
        let cmd = cli.find_subcommand(sub).unwrap();
        let arg = cmd
            .get_arguments()
            .chain(cli.get_arguments())
            .find(|a| a.get_id() == id)
            .unwrap_or_else(|| panic!("{sub} {id}"));
        let help = arg.get_help().unwrap().to_string();
        assert!(
            help.contains(&format!("[range: {}]", range.describe())),
            "{help}"
        );
        let flag = format!("--{}", id.replace('_', "-"));
        let accepts = |v: f64| {
            let text = format!("{v}");
            Cli::try_parse_from(["stablesurf", sub, "x", "-o", "y", &flag, &text]).is_ok()
        };
        assert!(accepts(range.min) && accepts(range.max), "{flag}");
        let step = if range.integer { 1.0 } else { range.max * 1e-9 };
        assert!(!accepts(range.max + step), "{flag}");
        if range.min > 0.0 {
            let below = if range.integer {
                range.min - 1.0
            } else {
                range.min * (1.0 - 1e-9)
            };
            assert!(!accepts(below), "{flag}");
        }
    }
    assert!(
        Cli::try_parse_from(["stablesurf", "fit", "x", "-o", "y", "--kappa", "-1e-300"]).is_err()
    );
    assert!(Cli::try_parse_from(["stablesurf", "fit", "x", "-o", "y", "--kappa", "AUTO"]).is_ok());
}

#[test]
fn trim_takes_auto_off_or_a_factor() {
    let trim = |v: &str| {
        Cli::try_parse_from(["stablesurf", "run", "x", "-o", "y", "--trim", v]).map(|c| {
            let CommandArgs::Run(r) = c.command else {
                panic!()
            };
            r.trim
        })
    };
    assert_eq!(trim("auto").unwrap(), Some(TrimArg::Auto));
    assert_eq!(trim("OFF").unwrap(), Some(TrimArg::Off));
    assert_eq!(trim("2.5").unwrap(), Some(TrimArg::Factor(2.5)));
    for bad in ["0", "-3", "x", "1e9", "nan"] {
        let err = trim(bad).unwrap_err();
        assert_eq!(err.exit_code(), 2, "{bad}");
        assert!(
            err.to_string()
                .contains("--trim takes auto, off or a number"),
            "{err}"
        );
    }
    let CommandArgs::Run(r) = parse(&["run", "-o", "out"]).command else {
        panic!()
    };
    assert_eq!(r.trim, None);
}

#[test]
fn missing_output_is_a_usage_error() {
    let err = Cli::try_parse_from(["stablesurf", "run"]).unwrap_err();
    assert_eq!(err.exit_code(), 2);
}

/// The closed choices take the spellings they always took: `--normals`, `--method` and
/// `--kappa-rule` in any case, `--normals` and `--formats` with spaces around a value,
/// `--mode` and `--view` exactly; anything else is a usage error naming the flag.
#[test]
fn choices_take_their_spellings() {
    let run = |flags: &[&str]| {
        let args = ["stablesurf", "run", "-o", "out"].iter().chain(flags);
        Cli::try_parse_from(args).map(|c| match c.command {
            CommandArgs::Run(r) => r,
            _ => panic!(),
        })
    };
    let r = run(&[
        "--normals",
        " PCA",
        "--method",
        "3LRR",
        "--kappa-rule",
        "Paper",
    ])
    .unwrap();
    assert_eq!(r.normals.source, SourceArg::Pca);
    assert_eq!(r.fit.method, MethodArg::ThreeLrr);
    assert_eq!(r.fit.kappa_rule, KappaRuleArg::Paper);
    let r = run(&["--formats", "glb, ply ,json", "--mode", "global"]).unwrap();
    assert_eq!(r.formats, [FormatArg::Glb, FormatArg::Ply, FormatArg::Json]);
    assert_eq!(r.mode(), ModeArg::Global);
    assert_eq!(run(&[]).unwrap().mode(), ModeArg::Detail);
    for (flag, bad) in [
        ("--normals", "normal"),
        ("--method", "qr"),
        ("--kappa-rule", "strict"),
        ("--formats", "glb,obj"),
        ("--mode", "Global"),
    ] {
        let err = run(&[flag, bad]).unwrap_err();
        assert_eq!(err.exit_code(), 2, "{flag} {bad}");
        assert!(err.to_string().contains(flag), "{err}");
    }
    let view = |v: &str| {
        Cli::try_parse_from(["stablesurf", "render", "m.ply", "-o", "p.png", "--view", v]).map(
            |c| match c.command {
                CommandArgs::Render(r) => r.view,
                _ => panic!(),
            },
        )
    };
    assert_eq!(view("top").unwrap(), ViewArg::Top);
    assert_eq!(view("Top").unwrap_err().exit_code(), 2);
    assert_eq!(spelling(&MethodArg::ThreeL), "3l");
    assert_eq!(spelling(&ModeArg::Detail), "detail");
}

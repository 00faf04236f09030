//! Bad configurations, written from a user's mistakes, through the real binary.
//!
//! Every case runs `chaoscope run`, `produce` or `map` on one spoiled config, with its output
//! pointed into an empty directory and its working directory in another, and must give:
//! a non-zero exit that is not a panic (exit 101, "panicked"), exactly one line on stderr that
//! names the key and the problem, and no file left behind in either directory.
//!
//! The resource estimate (a run longer than a day or larger than the machine's memory is
//! refused before it starts; `--force` runs it anyway) is tested at the end.

use crate::common;

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use crate::common::{CHAOSCOPE, unique_run};

/// A short valid run (the paper's chaotic Henon-Heiles orbit to t = 1).
const RUN: &str = r#"
[model]
name = "henon-heiles"

[orbit]
q = [0.0, -0.25]
p = [0.0, 0.0]
energy = 0.125
solve_for = "p1"

[integrator]
method = "aba864"
h = 0.01
t_final = 1.0

[deviations]
k = 4
sets = 2
seed = 1

[[scheme]]
name = "vm"
method = "vm"
d0 = 1e-8
tau = 0.5
orthonormalize = "rescale"
"#;

/// The same run with explicit deviation vectors instead of random sets.
const EXPLICIT: &str = r#"
[model]
name = "henon-heiles"

[orbit]
q = [0.0, -0.25]
p = [0.0, 0.0]
energy = 0.125
solve_for = "p1"

[integrator]
method = "aba864"
h = 0.01
t_final = 1.0

[deviations]
k = 2
vectors = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]]

[[scheme]]
name = "vm"
method = "vm"
d0 = 1e-8
tau = 0.5
"#;

/// The DDNLS example: a 21-site block of a 200-site chain excited by its norm.
const DDNLS: &str = include_str!("../examples/models/ddnls-block.toml");

/// A small FPUT chain (model keys other than Henon-Heiles').
const FPUT: &str = r#"
[model]
name = "fput-beta"
n = 3
beta = 1.0

[orbit]
q = [0.1, -0.2, 0.3]
p = [0.0, 0.1, 0.0]

[integrator]
method = "aba864"
h = 0.05
t_final = 1.0

[deviations]
k = 2
sets = 1

[[scheme]]
name = "mpm"
method = "mpm"
d0 = 1e-8
tau = 0.5
"#;

/// A small disordered Klein-Gordon chain (a potential with a drawn array parameter).
const DKG: &str = r#"
[model]
name = "potential"
n = 4
boundary = "fixed"
params = { W = 4.0, eps = { uniform = [0.5, 1.5], seed = 1 } }
potential = """
  sum(i = 1..N, eps[i]/2*q[i]^2 + q[i]^4/4)
+ sum(i = 0..N, (q[i+1] - q[i])^2/(2*W))"""

[orbit]
excite = { sites = 2, energy = 0.5 }

[integrator]
method = "aba864"
h = 0.05
t_final = 1.0

[deviations]
k = 2
sets = 1

[[scheme]]
name = "mpm"
method = "mpm"
d0 = 1e-8
tau = 0.5
"#;

/// A small valid map (3 x 2 points of the paper's section).
const MAP: &str = r#"
[model]
name = "henon-heiles"

[orbit]
q = [0.0, 0.0]
p = [0.0, 0.0]
energy = 0.125
solve_for = "p1"

[integrator]
method = "aba864"
h = 0.01
t_final = 1.0

[deviations]
k = 2
sets = 2
seed = 1

[[scheme]]
name = "mpm"
method = "mpm"
d0 = 1e-8
tau = 0.5

[map]
x = { coord = "q2", min = -0.4, max = 0.6, n = 3 }
y = { coord = "p2", min = -0.4, max = 0.4, n = 2 }
indicator = "gali"
"#;

/// A `[[sweep]]` of 20000 schemes, before the base config's own scheme.
const MANY_SWEPT: &str = "[[sweep]]\nname = \"mpm\"\nmethod = \"mpm\"\n\
    d0 = { from = 1e-14, to = 1e-2, count = 20000 }\ntau = 0.5\n\n[[scheme]]";

#[derive(Debug, Clone, Copy, PartialEq)]
enum Cmd {
    Run,
    Produce,
    Map,
    /// `section CONFIG --vary q2 --from -0.1 --to 0.1 --count 30 --csv OUT`.
    Section,
}

struct Case {
    name: &'static str,
    cmd: Cmd,
    config: Vec<u8>,
    /// The key the one-line message must name.
    key: &'static str,
    /// A fragment of the problem the message must state (case-insensitive).
    problem: &'static str,
}

/// `base` with `from` (which must occur exactly once) replaced by `to`.
fn spoil(base: &str, from: &str, to: &str) -> Vec<u8> {
    assert_eq!(
        base.matches(from).count(),
        1,
        "{from:?} must occur exactly once in the base config"
    );
    base.replacen(from, to, 1).into_bytes()
}

fn case(
    name: &'static str,
    cmd: Cmd,
    config: Vec<u8>,
    key: &'static str,
    problem: &'static str,
) -> Case {
    Case {
        name,
        cmd,
        config,
        key,
        problem,
    }
}

#[rustfmt::skip]
fn cases() -> Vec<Case> {
    use Cmd::*;
    let run = |name, from, to, key, problem| case(name, Run, spoil(RUN, from, to), key, problem);
    let explicit =
        |name, from, to, key, problem| case(name, Run, spoil(EXPLICIT, from, to), key, problem);
    let fput = |name, from, to, key, problem| case(name, Run, spoil(FPUT, from, to), key, problem);
    let map = |name, from, to, key, problem| case(name, Map, spoil(MAP, from, to), key, problem);
    let dkg = |name, from, to, key, problem| case(name, Run, spoil(DKG, from, to), key, problem);
    let example = |file: &str| {
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join(file)).unwrap()
    };
    let (standard_k, lorenz_mle) =
        (example("examples/maps/standard-map-k-sali.toml"), example("examples/maps/lorenz-mle.toml"));
    let by_k = |name, from, to, key, problem| case(name, Map, spoil(&standard_k, from, to), key, problem);
    let by_rho = |name, from, to, key, problem| case(name, Map, spoil(&lorenz_mle, from, to), key, problem);
    let many_schemes = {
        let mut text = RUN.to_string();
        for i in 0..12_000 {
            text.push_str(&format!(
                "[[scheme]]\nname = \"s{i}\"\nmethod = \"mpm\"\nd0 = 1e-8\ntau = 0.5\n"
            ));
        }
        text.into_bytes()
    };
    let binary: Vec<u8> = (0..4096u32)
        .map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8)
        .collect();
    vec![
        // The time step.
        run("h zero", "h = 0.01", "h = 0.0", "integrator.h", "finite positive"),
        run("h negative", "h = 0.01", "h = -0.01", "integrator.h", "finite positive"),
        run("h NaN", "h = 0.01", "h = nan", "integrator.h", "finite positive"),
        run("h infinite", "h = 0.01", "h = inf", "integrator.h", "finite positive"),
        run("h absurdly small", "h = 0.01", "h = 1e-300", "integrator.t_final", "steps"),
        run("h longer than the run", "h = 0.01", "h = 5.0", "integrator.t_final", "shorter than one step"),
        run("h a string", "h = 0.01", "h = \"0.01\"", "integrator.h", "invalid type"),
        run("h missing", "h = 0.01\n", "", "integrator.h", "missing"),
        // The horizon.
        run("t_final zero", "t_final = 1.0", "t_final = 0.0", "integrator.t_final", "finite positive"),
        run("t_final negative", "t_final = 1.0", "t_final = -1.0", "integrator.t_final", "finite positive"),
        run("t_final NaN", "t_final = 1.0", "t_final = nan", "integrator.t_final", "finite positive"),
        run("t_final infinite", "t_final = 1.0", "t_final = inf", "integrator.t_final", "finite positive"),
        run("t_final not a multiple of h", "t_final = 1.0", "t_final = 1.005", "integrator.t_final", "whole number"),
        run("t_final absurd", "t_final = 1.0", "t_final = 1e300", "integrator.t_final", "steps"),
        // The renormalization period.
        run("tau not a multiple of h", "tau = 0.5", "tau = 0.015", "scheme[0].tau", "whole number"),
        run("tau smaller than h", "tau = 0.5", "tau = 0.001", "scheme[0].tau", "shorter than one step"),
        run("tau zero", "tau = 0.5", "tau = 0.0", "scheme[0].tau", "finite positive"),
        run("tau negative", "tau = 0.5", "tau = -0.5", "scheme[0].tau", "finite positive"),
        run("tau NaN", "tau = 0.5", "tau = nan", "scheme[0].tau", "finite positive"),
        run("tau longer than the run", "tau = 0.5", "tau = 2.0", "scheme[0].tau", "longer than the run"),
        // d0.
        run("d0 zero", "d0 = 1e-8", "d0 = 0.0", "scheme[0].d0", "finite positive"),
        run("d0 negative", "d0 = 1e-8", "d0 = -1e-8", "scheme[0].d0", "finite positive"),
        run("d0 NaN", "d0 = 1e-8", "d0 = nan", "scheme[0].d0", "finite positive"),
        run("d0 infinite", "d0 = 1e-8", "d0 = inf", "scheme[0].d0", "finite positive"),
        // k and sets.
        run("k zero", "k = 4", "k = 0", "deviations.k", "between 1 and 2n"),
        run("k above 2N", "k = 4", "k = 5", "deviations.k", "between 1 and 2n"),
        run("k negative", "k = 4", "k = -1", "deviations.k", "invalid value"),
        run("sets zero", "sets = 2", "sets = 0", "deviations.sets", "between 1 and"),
        run("sets absurd", "sets = 2", "sets = 1000000000", "deviations.sets", "gib"),
        run("seed negative", "seed = 1", "seed = -1", "deviations.seed", "invalid value"),
        // Unknown names and keys.
        run("unknown model", "\"henon-heiles\"", "\"henon-heils\"", "model.name", "unknown model"),
        run("model name with a newline", "\"henon-heiles\"", "\"henon\\nheiles\"", "model.name", "unknown model 'henon\\nheiles'"),
        run("unknown integrator", "\"aba864\"", "\"rk4\"", "integrator.method", "unknown method"),
        run("unknown method", "method = \"vm\"", "method = \"lyapunov\"", "scheme[0].method", "not vm or mpm"),
        run("unknown orthonormalization", "\"rescale\"", "\"gram-schmidt\"", "scheme[0].orthonormalize", "not rescale or qr"),
        run("unknown key", "h = 0.01", "h = 0.01\ndt = 0.01", "integrator.dt", "unknown field"),
        run("unknown table", "[deviations]", "[output]\ndir = \"x\"\n\n[deviations]", "output", "unknown field"),
        run("misspelled scheme table", "[[scheme]]", "[[schemes]]", "schemes", "unknown field"),
        run("duplicate key", "h = 0.01", "h = 0.01\nh = 0.02", "integrator.h", "duplicate key"),
        run("key without value", "h = 0.01", "h =", "integrator.h", "expected"),
        run("duplicate scheme name", "orthonormalize = \"rescale\"", "orthonormalize = \"rescale\"\n[[scheme]]\nname = \"vm\"\nmethod = \"mpm\"\nd0 = 1e-8\ntau = 0.5", "scheme[1].name", "used twice"),
        run("no scheme", "[[scheme]]\nname = \"vm\"\nmethod = \"vm\"\nd0 = 1e-8\ntau = 0.5\northonormalize = \"rescale\"\n", "", "scheme", "at least one"),
        run("bad run name", "[model]", "[run]\nname = \"../x\"\n\n[model]", "run.name", "letters"),
        // Vectors and initial conditions.
        run("q too short", "q = [0.0, -0.25]", "q = [0.0]", "orbit.q", "needs 2 positions"),
        run("p too long", "p = [0.0, 0.0]", "p = [0.0, 0.0, 0.0]", "orbit.p", "needs 2 momenta"),
        run("q NaN", "q = [0.0, -0.25]", "q = [nan, -0.25]", "orbit.q", "not finite"),
        run("p infinite", "p = [0.0, 0.0]", "p = [0.0, inf]", "orbit.p", "not finite"),
        run("energy NaN", "energy = 0.125", "energy = nan", "orbit.energy", "finite"),
        run("energy infinite", "energy = 0.125", "energy = inf", "orbit.energy", "finite"),
        run("energy no momentum reaches", "energy = 0.125", "energy = -0.5", "orbit.energy", "no real p1"),
        run("solve_for a position", "solve_for = \"p1\"", "solve_for = \"q1\"", "orbit.solve_for", "momentum"),
        run("solve_for p0", "solve_for = \"p1\"", "solve_for = \"p0\"", "orbit.solve_for", "momentum"),
        run("solve_for beyond N", "solve_for = \"p1\"", "solve_for = \"p3\"", "orbit.solve_for", "momentum"),
        run("energy without solve_for", "solve_for = \"p1\"\n", "", "orbit.energy", "solve_for"),
        explicit("explicit vector too short", "[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]", "[1.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]", "deviations.vectors", "length"),
        explicit("explicit vectors dependent", "[0.0, 1.0, 0.0, 0.0]]", "[-2.0, 0.0, 0.0, 0.0]]", "deviations.vectors", "combination"),
        explicit("explicit zero vector", "[0.0, 1.0, 0.0, 0.0]]", "[0.0, 0.0, 0.0, 0.0]]", "deviations.vectors", "combination"),
        explicit("explicit vector NaN", "[0.0, 1.0, 0.0, 0.0]]", "[0.0, nan, 0.0, 0.0]]", "deviations.vectors", "not finite"),
        explicit("explicit vectors fewer than k", "k = 2", "k = 3", "deviations.vectors", "k = 3 but 2 vectors"),
        explicit("explicit vectors with sets", "k = 2", "k = 2\nsets = 4", "deviations.sets", "exactly one set"),
        // Models.
        fput("fput n zero", "n = 3", "n = 0", "model.n", "between 1 and"),
        fput("fput n absurd", "n = 3", "n = 100000000", "model.n", "between 1 and"),
        fput("fput n missing", "n = 3\n", "", "model.n", "needs the number"),
        fput("fput beta NaN", "beta = 1.0", "beta = nan", "model.beta", "finite"),
        fput("fput unknown preset", "q = [0.1, -0.2, 0.3]\np = [0.0, 0.1, 0.0]", "preset = \"spo9\"\nenergy = 1.0", "orbit.preset", "no preset"),
        run("henon-heiles with n", "name = \"henon-heiles\"", "name = \"henon-heiles\"\nn = 3", "model.n", "2 degrees of freedom"),
        // Files.
        case("empty file", Run, Vec::new(), "model", "the [model] table is missing"),
        case("binary file", Run, binary.clone(), "run.toml", "not a text file"),
        case("huge file", Run, huge_config(), "run.toml", "larger than"),
        case("twelve thousand schemes", Run, many_schemes, "scheme", "exceed the limit"),
        run("sweep of 20000 schemes", "[[scheme]]", MANY_SWEPT, "sweep[0].d0", "too many"),
        run("sweep with an empty range", "[[scheme]]", "[[sweep]]\nname = \"m\"\nmethod = \"mpm\"\nd0 = { from = 1e-8, to = 1e-9, count = 3 }\ntau = 0.5\n\n[[scheme]]", "sweep[0].d0", "from"),
        // The producer alone, from a file and from stdin.
        case("produce: h zero", Produce, spoil(RUN, "h = 0.01", "h = 0.0"), "integrator.h", "finite positive"),
        case("produce: binary stdin", Produce, binary, "stdin", "not a text file"),
        case("produce: unknown key", Produce, spoil(RUN, "k = 4", "k = 4\nvector = 1"), "deviations.vector", "unknown field"),
        // Maps.
        map("map grid of zero points", "n = 3 }", "n = 0 }", "map.x.n", "between 1 and"),
        map("map grid absurdly fine", "n = 3 }", "n = 10000000 }", "map.x.n", "between 1 and"),
        map("map unknown coordinate", "coord = \"q2\"", "coord = \"q3\"", "map.x.coord", "not a coordinate"),
        map("map coordinate not a name", "coord = \"p2\"", "coord = \"z\"", "map.y.coord", "not a coordinate"),
        map("map same coordinate twice", "coord = \"p2\"", "coord = \"q2\"", "map.y.coord", "same coordinate"),
        by_k("map parameter axis of no parameter", "param = \"K\"", "param = \"Q\"", "map.x.param", "'Q' is not a parameter of [model] params (scalars: K)"),
        by_k("map axis both coordinate and parameter", "{ param = \"K\",", "{ coord = \"x1\", param = \"K\",", "map.x.param", "coord = \"x1\" and param = \"K\" both given"),
        by_k("map coordinate axis naming a parameter", "{ param = \"K\",", "{ coord = \"K\",", "map.x.coord", "'K' is a parameter, not a coordinate"),
        by_k("map axis of neither", "{ param = \"K\",", "{", "map.x.coord", "needs coord"),
        by_k("map parameter axis over an array parameter", "params = { K = 1.0 }", "params = { K = [1.0, 2.0] }", "map.x.param", "'K' is an array parameter"),
        by_rho("map the same parameter twice", "param = \"sigma\"", "param = \"rho\"", "map.y.param", "same parameter"),
        by_rho("map parameter axis of an adaptive flow", "method = \"rk4\"", "method = \"dop853\"\nrtol = 1e-9\natol = 1e-9", "map.x.param", "batched kernel"),
        map("map parameter axis of a built-in model", "coord = \"q2\"", "param = \"q2\"", "map.x.param", "henon-heiles has no parameters to put on an axis"),
        map("map min above max", "min = -0.4, max = 0.6", "min = 0.6, max = -0.4", "map.x.min", "min <= max"),
        map("map min NaN", "min = -0.4, max = 0.4", "min = nan, max = 0.4", "map.y.min", "finite"),
        // Grids whose ends are finite but whose width, or a line on the way to the last, is not.
        map("map axis of width beyond f64", "min = -0.4, max = 0.6", "min = -1e308, max = 1e308", "map.x.max", "too far apart"),
        map("map axis whose lines overflow", "min = -0.4, max = 0.6", "min = 0.0, max = 1e308", "map.x.max", "too far apart"),
        by_k("map parameter axis beyond f64", "min = 0.0, max = 3.0", "min = -1e308, max = 1e308", "map.x.max", "too far apart"),
        // Initial conditions whose momentum, computed from an energy, would not be finite.
        map("map energy beyond f64", "energy = 0.125", "energy = 1e308", "orbit.energy", "twice it"),
        run("energy whose momentum overflows", "energy = 0.125", "energy = 1e308", "orbit.energy", "too large"),
        dkg("excitation whose momentum overflows", "excite = { sites = 2, energy = 0.5 }", "excite = { sites = 2, energy = 1e308 }", "orbit.excite.energy", "too large"),
        // The parameter's fault named, not the orbit's: 0/0 in the coupling 1/(2W).
        dkg("a coupling that divides by W = 0", "W = 4.0", "W = 0.0", "orbit", "'/' at line 2, column 34 of the potential gave NaN"),
        // Arrays of fixed length with entries beyond it, or of another type.
        dkg("drawn array with extra entries", "uniform = [0.5, 1.5]", "uniform = [0.5, 1.5, \"x\", {a = 1}]", "model.params.eps", "invalid type: string \"x\""),
        dkg("drawn array with a third number", "uniform = [0.5, 1.5]", "uniform = [0.5, 1.5, 2.5]", "model.params.eps.uniform", "two numbers [a, b], not 3"),
        dkg("drawn array of one number", "uniform = [0.5, 1.5]", "uniform = [0.5]", "model.params.eps.uniform", "two numbers [a, b], not 1"),
        dkg("drawn array entry a string", "uniform = [0.5, 1.5]", "uniform = [0.5, \"x\"]", "model.params", "invalid type"),
        map("map unknown indicator", "indicator = \"gali\"", "indicator = \"ofli\"", "map.indicator", "is not gali"),
        map("map unknown route", "indicator = \"gali\"", "indicator = \"gali\"\nroute = \"shared\"", "map.route", "is not per-set or basis"),
        map("map MPM propagator route with a large d0", "d0 = 1e-8\ntau = 0.5\n\n[map]", "d0 = 1e-3\ntau = 0.5\n\n[map]\nroute = \"propagator\"", "map.route", "valid for"),
        map("map k above 2N", "indicator = \"gali\"", "indicator = \"gali\"\nk = 5", "map.k", "2n"),
        map("map threshold negative", "indicator = \"gali\"", "indicator = \"gali-time\"\nthreshold = -1.0", "map.threshold", "threshold"),
        map("map two schemes", "[map]", "[[scheme]]\nname = \"vm\"\nmethod = \"vm\"\nd0 = 1e-8\ntau = 0.5\n\n[map]", "scheme", "exactly one"),
        map("map solves for a grid axis", "solve_for = \"p1\"", "solve_for = \"p2\"", "orbit.solve_for", "grid axis"),
        map("map unknown key", "indicator = \"gali\"", "indicator = \"gali\"\nresolution = 3", "map.resolution", "unknown field"),
        map("map h zero", "h = 0.01", "h = 0.0", "integrator.h", "finite positive"),
        case("map without [map]", Map, RUN.as_bytes().to_vec(), "map", "[map] section"),
    ]
}

/// A config of 20 MiB (a valid one followed by comment lines): beyond the size limit.
fn huge_config() -> Vec<u8> {
    let mut text = RUN.as_bytes().to_vec();
    let line = b"# padding padding padding padding padding padding padding padding\n";
    while text.len() < 20 << 20 {
        text.extend_from_slice(line);
    }
    text
}

/// Runs one case in fresh directories; returns (exit code, stderr, files left behind).
fn run_case(c: &Case, dir: &Path) -> (Option<i32>, String, Vec<String>) {
    let cwd = dir.join("cwd");
    let out = dir.join("out");
    let cfg_dir = dir.join("cfg");
    for d in [&cwd, &out, &cfg_dir] {
        std::fs::create_dir_all(d).unwrap();
    }
    let config = cfg_dir.join("run.toml");
    std::fs::write(&config, &c.config).unwrap();
    let out_file = out.join("out.mcap");
    let mut command = Command::new(CHAOSCOPE);
    command
        .current_dir(&cwd)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    let stdin_config = c.name.contains("stdin");
    let config_arg = if stdin_config {
        "-".to_string()
    } else {
        config.to_str().unwrap().to_string()
    };
    match c.cmd {
        Cmd::Run => {
            command.args(["run", &config_arg, "--out", out_file.to_str().unwrap()]);
        }
        Cmd::Produce => {
            command.args([
                "produce",
                &config_arg,
                "--run",
                &unique_run("badcfg"),
                "--recorders",
                "0",
                "--no-progress",
            ]);
        }
        Cmd::Map => {
            command.args([
                "map",
                &config_arg,
                "--out",
                out_file.to_str().unwrap(),
                "--no-progress",
                "--threads",
                "1",
            ]);
        }
        Cmd::Section => {
            command.args([
                "section",
                &config_arg,
                "--vary",
                "q2",
                "--from",
                "-0.1",
                "--to",
                "0.1",
                "--count",
                "30",
                "--csv",
                out.join("section.csv").to_str().unwrap(),
            ]);
        }
    }
    if stdin_config {
        command.stdin(Stdio::piped());
    }
    let mut child = command.spawn().expect("spawn chaoscope");
    if stdin_config {
        use std::io::Write;
        let mut stdin = child.stdin.take().unwrap();
        // The process may refuse the input before reading all of it.
        let _ = stdin.write_all(&c.config);
    }
    let start = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if start.elapsed() > Duration::from_secs(60) {
            let _ = child.kill();
            panic!("{}: still running after 60 s", c.name);
        }
        std::thread::sleep(Duration::from_millis(5));
    };
    let mut stderr = String::new();
    std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut stderr).unwrap();
    let left = [&cwd, &out]
        .iter()
        .flat_map(|d| std::fs::read_dir(d).unwrap())
        .map(|e| e.unwrap().path().display().to_string())
        .collect();
    (status.code(), stderr, left)
}

#[test]
fn the_base_configs_are_valid() {
    // A spoiled copy of a config that was already bad would prove nothing.
    use chaoscope_dynamics::map::MapSpec;
    use chaoscope_dynamics::spec::RunSpec;
    use chaoscope_schemas::config::RunConfig;
    for base in [RUN, EXPLICIT, FPUT, DKG] {
        RunSpec::from_config(&RunConfig::from_toml(base).unwrap()).unwrap();
    }
    MapSpec::from_config(&RunConfig::from_toml(MAP).unwrap()).unwrap();
}

#[test]
fn every_bad_config_is_one_line_naming_the_key_and_leaves_nothing() {
    let cases = cases();
    assert!(cases.len() >= 40, "{} cases", cases.len());
    let tmp = tempfile::tempdir().unwrap();
    let mut failures = Vec::new();
    for (i, c) in cases.iter().enumerate() {
        let dir = tmp.path().join(i.to_string());
        let (code, stderr, left) = run_case(c, &dir);
        let lines: Vec<&str> = stderr.lines().filter(|l| !l.trim().is_empty()).collect();
        let line = lines.first().copied().unwrap_or("");
        let lower = line.to_lowercase();
        let mut problems = Vec::new();
        if code == Some(0) {
            problems.push("exit status 0".to_string());
        }
        if code == Some(101) || code.is_none() || stderr.contains("panicked") {
            problems.push(format!("panic or signal (exit {code:?})"));
        }
        if !left.is_empty() {
            problems.push(format!("files left behind: {left:?}"));
        }
        if lines.len() != 1 {
            problems.push(format!("{} lines on stderr", lines.len()));
        }
        if !line.contains(c.key) {
            problems.push(format!("does not name {}", c.key));
        }
        if !lower.contains(&c.problem.to_lowercase()) {
            problems.push(format!("does not say {:?}", c.problem));
        }
        if !problems.is_empty() {
            failures.push(format!(
                "{}: {}\n  stderr: {stderr}",
                c.name,
                problems.join("; ")
            ));
        }
        eprintln!("{:>3} {:<40} exit {code:?}: {line}", i, c.name);
    }
    assert!(
        failures.is_empty(),
        "{} of {} cases failed:\n{}",
        failures.len(),
        cases.len(),
        failures.join("\n")
    );
}

/// The line (1-based) of `text` holding `needle`, which must occur once.
fn line_of(text: &str, needle: &str) -> usize {
    assert_eq!(text.matches(needle).count(), 1, "{needle:?}");
    text[..text.find(needle).unwrap()].matches('\n').count() + 1
}

#[test]
fn semantic_errors_name_the_file_and_the_line_of_their_key() {
    // A value the TOML parser accepts and the validation refuses: the message names the file
    // and the key's line and column, as a TOML error does (`in FILE: invalid run
    // configuration: KEY (line L, column C): ...`), in every command that reads the file.
    use Cmd::*;
    let tmp = tempfile::tempdir().unwrap();
    let cases = [
        (
            Run,
            RUN,
            "h = 0.01",
            "h = -0.01",
            "invalid run configuration: integrator.h",
        ),
        (
            Produce,
            RUN,
            "h = 0.01",
            "h = 0.0",
            "invalid run configuration: integrator.h",
        ),
        (
            Run,
            RUN,
            "d0 = 1e-8",
            "d0 = -1e-8",
            "invalid run configuration: scheme[0].d0",
        ),
        (
            Section,
            RUN,
            "k = 4",
            "k = 9",
            "invalid run configuration: deviations.k",
        ),
        (
            Map,
            MAP,
            "indicator = \"gali\"",
            "indicator = \"galli\"",
            "invalid map configuration: map.indicator",
        ),
        (
            Produce,
            FPUT,
            "beta = 1.0",
            "beta = nan",
            "invalid run configuration: model.beta",
        ),
        (
            Run,
            DDNLS,
            "W = 4.0",
            "W = -4.0",
            "invalid run configuration: model.W",
        ),
        (
            Run,
            DDNLS,
            "lattice = \"chain\"",
            "lattice = \"cube\"",
            "invalid run configuration: model.lattice",
        ),
    ];
    for (i, (cmd, base, from, to, says)) in cases.into_iter().enumerate() {
        let text = String::from_utf8(spoil(base, from, to)).unwrap();
        let line = line_of(&text, to.lines().next().unwrap());
        let c = case("semantic", cmd, text.into_bytes(), "", "");
        let dir = tmp.path().join(i.to_string());
        let (code, stderr, _) = run_case(&c, &dir);
        assert_eq!(code, Some(1), "{stderr}");
        let config = dir.join("cfg").join("run.toml");
        let want = format!("in {}: ", config.display());
        assert!(stderr.contains(&want), "{stderr:?} does not name the file");
        assert!(stderr.contains(says), "{stderr:?} does not say {says:?}");
        assert!(
            stderr.contains(&format!("(line {line}, column 1): ")),
            "{stderr:?} does not give line {line}"
        );
        assert_eq!(stderr.lines().count(), 1, "{stderr}");
    }
    // A key the user left out (a map's h given where a Hamiltonian needs one): its table.
    let text = String::from_utf8(spoil(RUN, "h = 0.01\n", "")).unwrap();
    let line = line_of(&text, "[integrator]");
    let dir = tmp.path().join("missing");
    let (code, stderr, _) = run_case(&case("missing", Run, text.into_bytes(), "", ""), &dir);
    assert_eq!(code, Some(1), "{stderr}");
    assert!(
        stderr.contains(&format!("integrator.h (line {line}, column 1): missing")),
        "{stderr}"
    );
    // A run name that would be a hidden file: its file and line, as any other key.
    let text = String::from_utf8(spoil(RUN, "[model]", "[run]\nname = \".h\"\n\n[model]")).unwrap();
    let line = line_of(&text, "name = \".h\"");
    let dir = tmp.path().join("run-name");
    let (code, stderr, _) = run_case(&case("run name", Run, text.into_bytes(), "", ""), &dir);
    assert_eq!(code, Some(1), "{stderr}");
    assert!(
        stderr.contains("in ") && stderr.contains("run.toml: "),
        "{stderr}"
    );
    assert!(
        stderr.contains(&format!(
            "run.name (line {line}, column 1): run name \".h\" starts with '.'"
        )),
        "{stderr}"
    );
    // The 0-1 test's observable: an expression that does not parse, one that names no
    // coordinate of the state (Henon-Heiles has q1, q2, p1, p2), one that reads none. Each is
    // refused before the run, in one line naming the key and its line.
    for (i, (expression, says)) in [
        ("q1 +* q2", "line 1, column"),
        ("q1 + q3", "q3"),
        ("2 * 3", "reads no coordinate"),
    ]
    .into_iter()
    .enumerate()
    {
        let table = format!("[analysis]\nzero_one_observable = \"{expression}\"\n\n[model]");
        let text = String::from_utf8(spoil(RUN, "[model]", &table)).unwrap();
        let line = line_of(&text, "zero_one_observable = ");
        let dir = tmp.path().join(format!("observable-{i}"));
        let (code, stderr, _) = run_case(&case("observable", Run, text.into_bytes(), "", ""), &dir);
        assert_eq!(code, Some(1), "{expression}: {stderr}");
        assert!(
            stderr.contains(&format!(
                "analysis.zero_one_observable (line {line}, column 1): "
            )) && stderr.contains(says),
            "{expression}: {stderr}"
        );
        assert_eq!(stderr.lines().count(), 1, "{stderr}");
    }
    // A table left out of the document: named as the table, not as a key of the first one.
    let orbit = "[orbit]\nq = [0.0, -0.25]\np = [0.0, 0.0]\nenergy = 0.125\nsolve_for = \"p1\"\n";
    let text = String::from_utf8(spoil(RUN, orbit, "")).unwrap();
    let dir = tmp.path().join("no-orbit");
    let (code, stderr, _) = run_case(&case("no orbit", Run, text.into_bytes(), "", ""), &dir);
    assert_eq!(code, Some(1), "{stderr}");
    assert!(
        stderr.contains("orbit: the [orbit] table is missing"),
        "{stderr}"
    );
    assert!(!stderr.contains("model.orbit"), "{stderr}");
}

/// Run names may hold dots (`h0.01`): they are file names and bus service names, and both
/// take them.
#[test]
fn run_names_may_hold_dots() {
    let tmp = tempfile::tempdir().unwrap();
    let text = RUN.replacen("[model]", "[run]\nname = \"h0.01\"\n\n[model]", 1);
    let (code, stdout, stderr) = config_check(&text, tmp.path());
    assert_eq!(code, Some(0), "{stdout}{stderr}");
}

/// `chaoscope config` on `text`: exit status, stdout and stderr.
fn config_check(text: &str, dir: &Path) -> (Option<i32>, String, String) {
    std::fs::create_dir_all(dir).unwrap();
    let path = dir.join("check.toml");
    std::fs::write(&path, text).unwrap();
    let out = Command::new(CHAOSCOPE)
        .args(["config", path.to_str().unwrap()])
        .output()
        .unwrap();
    let text = |b: Vec<u8>| String::from_utf8(b).unwrap();
    (out.status.code(), text(out.stdout), text(out.stderr))
}

/// The Henon map with `params`, `[integrator]` holding `integrator`, and `map` appended.
fn henon_map(params: &str, integrator: &str, map: &str) -> String {
    format!(
        "[model]\nname = \"map\"\nnext = [\"1 - a*x1^2 + x2\", \"b*x1\"]\nparams = {params}\n\
         modulo = [6.283185307179586, 0]\n[orbit]\nx = [0.1, 0.1]\n\
         [integrator]\n{integrator}\n[deviations]\nk = 2\nsets = 1\nseed = 1\n\
         [[scheme]]\nname = \"vm\"\nmethod = \"vm\"\nd0 = 1e-8\ntau = 1\n\
         orthonormalize = \"rescale\"\n{map}"
    )
}

#[test]
fn papercuts_of_maps_and_parameters_are_said_not_silent() {
    let tmp = tempfile::tempdir().unwrap();
    let used = "{ a = 1.4, b = 0.3 }";
    // A map needs no h (time counts iterations); any h but 1 is one line naming integrator.h.
    let (code, _, stderr) = config_check(&henon_map(used, "t_final = 10", ""), tmp.path());
    assert_eq!(code, Some(0), "{stderr}");
    assert!(stderr.is_empty(), "{stderr}");
    let (code, _, stderr) = config_check(&henon_map(used, "h = 0.1\nt_final = 10", ""), tmp.path());
    assert_eq!(code, Some(1), "{stderr}");
    assert!(stderr.contains("integrator.h (line 9, column 1): a map's time counts iterations"));
    assert_eq!(stderr.lines().count(), 1, "{stderr}");

    // An unused parameter: a warning naming it, and the run still succeeds.
    let unused = "{ a = 1.4, b = 0.3, unused = 3 }";
    let config = tmp.path().join("unused.toml");
    std::fs::write(&config, henon_map(unused, "t_final = 10", "")).unwrap();
    let out = Command::new(CHAOSCOPE)
        .current_dir(tmp.path())
        .args(["run", config.to_str().unwrap(), "--out", "unused.mcap"])
        .output()
        .unwrap();
    let stderr = String::from_utf8(out.stderr).unwrap();
    assert!(out.status.success(), "{stderr}");
    assert!(
        stderr.contains("warning: model.params.unused = 3 is used by no expression"),
        "{stderr}"
    );
    assert!(tmp.path().join("unused.mcap").is_file());

    // A grid over a whole period of x1 (0 and 2 pi are one point): a warning naming map.x
    // and the max that grids it once; none for x2, which has no period, nor for max < 2 pi.
    let axes = |max: &str| {
        format!(
            "[map]\nx = {{ coord = \"x1\", min = 0.0, max = {max}, n = 4 }}\n\
             y = {{ coord = \"x2\", min = -1.0, max = 1.0, n = 2 }}\nindicator = \"sali\"\n"
        )
    };
    let (code, _, stderr) = config_check(
        &henon_map(used, "t_final = 10", &axes("6.283185307179586")),
        tmp.path(),
    );
    assert_eq!(code, Some(0), "{stderr}");
    assert!(
        stderr.contains("warning: map.x: min = 0 and max = 6.283185307179586 are the same point")
            && stderr.contains("max = 4.71238898038469"),
        "{stderr}"
    );
    assert_eq!(stderr.lines().count(), 1, "{stderr}");
    let (code, _, stderr) = config_check(
        &henon_map(used, "t_final = 10", &axes("4.71238898038469")),
        tmp.path(),
    );
    assert_eq!(code, Some(0), "{stderr}");
    assert!(stderr.is_empty(), "{stderr}");

    // energy + solve_for: p may be left out.
    let no_p = String::from_utf8(spoil(RUN, "p = [0.0, 0.0]\n", "")).unwrap();
    let (code, _, stderr) = config_check(&no_p, tmp.path());
    assert_eq!(code, Some(0), "{stderr}");
}

/// FPUT N = 501 for 10^9 time units: days of computing.
const LONG_CHAIN: &str = r#"
[model]
name = "fput-beta"
n = 501

[orbit]
preset = "spo1"
energy = 50.0

[integrator]
method = "aba864"
h = 0.05
t_final = 1e9

[deviations]
k = 2

[[scheme]]
name = "m"
method = "mpm"
d0 = 1e-8
tau = 1.0
"#;

/// 200 vectors of a 10^6-dimensional chain: about 100 GiB of frames in flight alone (N odd:
/// the SPO1 preset exists for odd N only, which validation, now before the estimate, checks).
const WIDE_CHAIN: &str = r#"
[model]
name = "fput-beta"
n = 500001

[orbit]
preset = "spo1"
energy = 50.0

[integrator]
method = "aba864"
h = 0.05
t_final = 0.05

[deviations]
k = 200

[[scheme]]
name = "m"
method = "mpm"
d0 = 1e-8
tau = 0.05
"#;

fn text_case(
    name: &'static str,
    cmd: Cmd,
    text: &str,
    key: &'static str,
    problem: &'static str,
) -> Case {
    case(name, cmd, text.as_bytes().to_vec(), key, problem)
}

#[rustfmt::skip]
#[test]
fn runs_beyond_a_day_or_the_memory_are_refused_before_they_start() {
    let huge_map = spoil(
        &String::from_utf8(spoil(MAP, "n = 3 }", "n = 100000 }")).unwrap(),
        "n = 2 }",
        "n = 100000 }",
    );
    let long_map = spoil(
        &String::from_utf8(spoil(MAP, "t_final = 1.0", "t_final = 1e9")).unwrap(),
        "n = 3 }",
        "n = 1000 }",
    );
    // Every kind of system, its time from a calibration of the system itself: an `ode` flow
    // (Lorenz, dop853), a `map` model (the standard map) and a general `hamiltonian` (gl4).
    let (long_flow, long_iteration, long_hamiltonian) = (long_flow(), long_iteration(), long_hamiltonian());
    let cases = [
        case("run: Lorenz (ode) to 1e11", Cmd::Run, long_flow, "integrator.t_final", "would take about"),
        case("run: standard map (map) to 1e14", Cmd::Run, long_iteration, "integrator.t_final", "would take about"),
        case("run: magnetic HH (hamiltonian) to 1e11", Cmd::Run, long_hamiltonian, "integrator.t_final", "would take about"),
        case("map: standard map, 40000 points to 1e8", Cmd::Map, calibrated_map(), "integrator.t_final", "would take about"),
        text_case("run: FPUT 501 to 1e9", Cmd::Run, LONG_CHAIN, "integrator.t_final", "would take about"),
        text_case("produce: FPUT 501 to 1e9", Cmd::Produce, LONG_CHAIN, "integrator.t_final", "would take about"),
        text_case("run: 10^6-dimensional, k = 200", Cmd::Run, WIDE_CHAIN, "deviations.k", "memory"),
        case("map: 10^10 points", Cmd::Map, huge_map, "map.x.n", "memory"),
        case("section: 30 orbits to 1e9", Cmd::Section, long_map.clone(), "integrator.t_final", "would take about"),
        case("map: 2000 points to 1e9", Cmd::Map, long_map, "integrator.t_final", "would take about"),
    ];
    let tmp = tempfile::tempdir().unwrap();
    for (i, c) in cases.iter().enumerate() {
        let start = Instant::now();
        let (code, stderr, left) = run_case(c, &tmp.path().join(i.to_string()));
        eprintln!(
            "{}: exit {code:?} in {:?}: {stderr}",
            c.name,
            start.elapsed()
        );
        assert_eq!(code, Some(1), "{}: {stderr}", c.name);
        assert_eq!(stderr.lines().count(), 1, "{}: {stderr}", c.name);
        assert!(
            stderr.contains(&format!("error: {}: this would", c.key)),
            "{}: {stderr}",
            c.name
        );
        assert!(
            stderr.contains(c.problem) && stderr.contains("--force"),
            "{}: {stderr}",
            c.name
        );
        assert!(left.is_empty(), "{}: {left:?}", c.name);
        // Refused from the estimate, not after drawing directions or allocating.
        assert!(start.elapsed() < Duration::from_secs(5), "{}", c.name);
    }
}

/// An example of `examples/models` with its `t_final` spoiled.
fn long_example(name: &str, t_final: &str) -> Vec<u8> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("examples/models/{name}.toml"));
    let text = std::fs::read_to_string(path).unwrap();
    let line = text.lines().find(|l| l.starts_with("t_final = ")).unwrap();
    spoil(&text, line, &format!("t_final = {t_final}"))
}

/// The Lorenz flow (dop853, VM and MPM) to t = 1e11: 1e13 steps of several orbits and tangent
/// vectors, at least tens of nanoseconds each on any machine: years.
fn long_flow() -> Vec<u8> {
    long_example("lorenz", "1e11")
}

/// The standard map to 10^14 iterations, with its VM and MPM schemes (5 orbit-steps per
/// iteration, a sine each): at least about 10 ns an iteration on any machine, weeks.
fn long_iteration() -> Vec<u8> {
    long_example("standard-map", "1e14")
}

/// Henon-Heiles in a magnetic field (a `hamiltonian`, gl4 solved by fixed-point iteration) to
/// t = 1e11: 1e13 implicit steps, years.
fn long_hamiltonian() -> Vec<u8> {
    long_example("magnetic-henon-heiles", "1e11")
}

/// The standard map's SALI map (`examples/maps`) to 10^8 iterations: 200 x 200 points x 3
/// orbits x 1e8 steps = 1.2e13 orbit-steps. The former fixed cost (1 ns per orbit-step and
/// dimension, the same for every system) put it at 1.4 days on one core and a third of a day
/// on 4 (CI's machines have 2), and missed that a standard-map orbit-step (a sine through the
/// expression's callback, wrapping on the torus) costs tens of nanoseconds: the calibration
/// of the map's own kernel puts it at weeks.
fn calibrated_map() -> Vec<u8> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/maps/standard-map-sali.toml");
    let text = std::fs::read_to_string(path).unwrap();
    spoil(&text, "t_final = 1000\n", "t_final = 100000000\n")
}

/// Starts `args` (with `--force`), checks that it is still running after a while, interrupts it
/// and returns its exit code and stderr.
fn forced(args: &[&str], dir: &Path) -> (Option<i32>, String) {
    let mut child = Command::new(CHAOSCOPE)
        .args(args)
        .current_dir(dir)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_secs(3));
    assert!(
        child.try_wait().unwrap().is_none(),
        "{args:?} stopped although forced"
    );
    // SAFETY: kill(2) on our own child.
    unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
    let start = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if start.elapsed() > Duration::from_secs(60) {
            let _ = child.kill();
            panic!("{args:?} did not stop on SIGINT");
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let mut stderr = String::new();
    std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut stderr).unwrap();
    (status.code(), stderr)
}

#[test]
fn force_starts_what_the_estimate_refuses() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    std::fs::write(dir.join("long.toml"), LONG_CHAIN).unwrap();
    let long_map = spoil(MAP, "t_final = 1.0", "t_final = 1e9");
    let long_map = spoil(
        std::str::from_utf8(&long_map).unwrap(),
        "n = 3 }",
        "n = 1000 }",
    );
    std::fs::write(dir.join("map.toml"), long_map).unwrap();
    let run = unique_run("force");

    let (code, stderr) = forced(
        &[
            "produce",
            "long.toml",
            "--force",
            "--recorders",
            "0",
            "--no-progress",
            "--run",
            &run,
        ],
        dir,
    );
    assert_eq!(code, Some(130), "{stderr}");
    assert!(
        stderr.contains("--force: starting although integrator.t_final"),
        "{stderr}"
    );

    let (code, stderr) = forced(&["run", "long.toml", "--force", "--out", "long.mcap"], dir);
    assert_eq!(code, Some(130), "{stderr}");
    assert!(stderr.contains("--force: starting although"), "{stderr}");
    let summary = chaoscope_analyzer::summary::summarize(&dir.join("long.mcap")).unwrap();
    assert_eq!(summary.run_status, "interrupted", "{summary:?}");

    // The recording carries the configuration `run` refused: its replay (the same run with one
    // more scheme) is refused as well, before it writes anything, and starts with --force.
    let replay = ["replay", "long.mcap", "--tau", "2", "--out", "replay.mcap"];
    let start = Instant::now();
    let refused = Command::new(CHAOSCOPE)
        .args(replay)
        .current_dir(dir)
        .stdin(Stdio::null())
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&refused.stderr);
    eprintln!("replay refused in {:?}: {stderr}", start.elapsed());
    assert_eq!(refused.status.code(), Some(1), "{stderr}");
    assert_eq!(stderr.lines().count(), 1, "{stderr}");
    assert!(
        stderr.contains("error: integrator.t_final: this would take about")
            && (stderr.contains(" day") || stderr.contains(" year"))
            && stderr.contains("--force"),
        "{stderr}"
    );
    assert!(!dir.join("replay.mcap").exists());
    let forced_replay: Vec<&str> = replay.iter().copied().chain(["--force"]).collect();
    let (_, stderr) = forced(&forced_replay, dir);
    assert!(
        stderr.contains("--force: starting although integrator.t_final"),
        "{stderr}"
    );

    // A flow and a map model beyond a day start with --force.
    for (name, text) in [("flow", long_flow()), ("iteration", long_iteration())] {
        std::fs::write(dir.join(format!("{name}.toml")), text).unwrap();
        let (config, out) = (format!("{name}.toml"), format!("{name}.mcap"));
        let (code, stderr) = forced(
            &[
                "run",
                &config,
                "--force",
                "--out",
                &out,
                "--run",
                &unique_run(name),
            ],
            dir,
        );
        assert_eq!(code, Some(130), "{name}: {stderr}");
        assert!(
            stderr.contains("--force: starting although integrator.t_final"),
            "{name}: {stderr}"
        );
        let summary = chaoscope_analyzer::summary::summarize(&dir.join(&out)).unwrap();
        assert_eq!(summary.run_status, "interrupted", "{name}: {summary:?}");
    }

    let (code, stderr) = forced(
        &[
            "map",
            "map.toml",
            "--force",
            "--out",
            "map.mcap",
            "--no-progress",
            "--threads",
            "1",
        ],
        dir,
    );
    assert_eq!(code, Some(130), "{stderr}");
    assert!(stderr.contains("--force: starting although"), "{stderr}");
    assert!(dir.join("map.mcap").exists());
}

/// A command line that does not parse (a mistyped value, an unknown option, a missing
/// argument) exits with 64, sysexits' EX_USAGE, and none of the result statuses (0 to 3: 2 is
/// `replay`'s "the replayed orbit differs"); `--help` and `--version` answer with 0 (before:
/// clap's 2 for every usage error).
#[test]
fn usage_errors_have_a_status_of_their_own() {
    let status = |args: &[&str]| {
        let out = Command::new(CHAOSCOPE)
            .args(args)
            .stdin(Stdio::null())
            .output()
            .unwrap();
        (
            out.status.code(),
            String::from_utf8_lossy(&out.stdout).into_owned(),
            String::from_utf8_lossy(&out.stderr).into_owned(),
        )
    };
    for args in [
        &["replay", "x.mcap", "--tau", "abc", "--out", "y.mcap"][..],
        &["resume", "x.mcap", "--t-final", "soon"],
        &["map", "m.toml", "--out", "m.mcap", "--threads", "-1"],
        &["run", "--no-such-option"],
        &["replay", "x.mcap", "--tau", "1"],
        &["no-such-command"],
        &[],
    ] {
        let (code, stdout, stderr) = status(args);
        assert_eq!(code, Some(64), "{args:?}: {stderr}");
        assert!(stdout.is_empty(), "{args:?}: {stdout}");
        // clap's message: the error and where to read how the command is used.
        assert!(
            (stderr.contains("Usage:") || stderr.contains("try '--help'"))
                && !stderr.contains("panicked"),
            "{args:?}: {stderr}"
        );
    }
    for args in [
        &["--help"][..],
        &["--version"],
        &["replay", "--help"],
        &["help", "resume"],
    ] {
        let (code, stdout, stderr) = status(args);
        assert_eq!(code, Some(0), "{args:?}: {stderr}");
        assert!(
            !stdout.is_empty() && stderr.is_empty(),
            "{args:?}: {stderr}"
        );
    }
}

/// `resume --t-final` is estimated as `run` of the same configuration to that end: a 50-unit
/// Lorenz recording extended to 1e12 is refused in one line naming `--t-final`, before
/// anything is written (in place or elsewhere; the recording unchanged), and starts with
/// `--force` (before: it started at once and wrote 250 MB in 8 s where `run` refuses it).
#[test]
fn resume_to_a_new_end_is_estimated_as_run_is() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    std::fs::write(dir.join("lorenz.toml"), long_example("lorenz", "50.0")).unwrap();
    let run = Command::new(CHAOSCOPE)
        .args(["run", "lorenz.toml", "--out", "base.mcap", "--run"])
        .arg(unique_run("resume-estimate"))
        .current_dir(dir)
        .stdin(Stdio::null())
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let base = std::fs::read(dir.join("base.mcap")).unwrap();
    for out in [&["--out", "big.mcap"][..], &[]] {
        let args: Vec<&str> = ["resume", "base.mcap", "--t-final", "1e12"]
            .iter()
            .chain(out)
            .copied()
            .collect();
        let start = Instant::now();
        let refused = Command::new(CHAOSCOPE)
            .args(&args)
            .current_dir(dir)
            .stdin(Stdio::null())
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&refused.stderr);
        eprintln!("{args:?} refused in {:?}: {stderr}", start.elapsed());
        assert_eq!(refused.status.code(), Some(1), "{args:?}: {stderr}");
        assert_eq!(stderr.lines().count(), 1, "{args:?}: {stderr}");
        // 1e14 steps of dop853 with 3 tangent vectors and 3 nearby orbits: years on any
        // machine (a step of this flow is above 10 ns).
        assert!(
            stderr.contains("base.mcap: --t-final: this would take about")
                && stderr.contains(" year")
                && stderr.contains("--force"),
            "{args:?}: {stderr}"
        );
        let mut left: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        left.sort();
        assert_eq!(left, ["base.mcap", "lorenz.toml"], "{args:?}");
        assert!(
            std::fs::read(dir.join("base.mcap")).unwrap() == base,
            "{args:?}"
        );
    }
    let (code, stderr) = forced(
        &[
            "resume",
            "base.mcap",
            "--t-final",
            "1e12",
            "--out",
            "big.mcap",
            "--force",
        ],
        dir,
    );
    assert_eq!(code, Some(130), "{stderr}");
    assert!(
        stderr.contains("--force: starting although --t-final: this would take about"),
        "{stderr}"
    );
    let summary = chaoscope_analyzer::summary::summarize(&dir.join("big.mcap")).unwrap();
    assert_eq!(summary.run_status, "interrupted", "{summary:?}");
}

#[test]
fn the_estimate_refuses_no_example_and_no_test_run() {
    use chaoscope_dynamics::estimate::{self, Machine};
    use chaoscope_dynamics::map::MapSpec;
    use chaoscope_dynamics::spec::RunSpec;
    use chaoscope_schemas::config::{RunConfig, read_config_file};
    // The smallest machine the project runs on (CI: 2 cores, 24 GiB), with 8 GiB to spare.
    let machine = Machine {
        cores: 2,
        memory_bytes: Some(8 << 30),
    };
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut configs = vec![(
        "chaoscope run's default".to_string(),
        read_config_file(&root.join("src/cli/hh_chaotic.toml")).unwrap(),
    )];
    // Every kind of system (the models directory has flows, maps and general Hamiltonians):
    // the estimate reads the dimension of each from its validated spec.
    for dir in ["examples/paper/configs", "examples/maps", "examples/models"] {
        for e in std::fs::read_dir(root.join(dir)).unwrap() {
            let p = e.unwrap().path();
            if p.extension().is_some_and(|x| x == "toml") {
                configs.push((p.display().to_string(), read_config_file(&p).unwrap()));
            }
        }
    }
    configs.extend(
        [RUN, EXPLICIT, FPUT, MAP, DKG]
            .map(|t| ("a test base".to_string(), RunConfig::from_toml(t).unwrap())),
    );
    for (name, cfg) in &configs {
        let e = if cfg.map.is_some() {
            let spec = MapSpec::from_config(cfg).unwrap();
            estimate::map(&spec, spec.grid_points(), machine.cores)
        } else {
            let spec = RunSpec::from_config(cfg).unwrap();
            assert!(spec.dim() >= 2, "{name}");
            chaoscope_producer::estimate::run(&spec, &machine)
        };
        assert_eq!(e.refusal(&machine), None, "{name}: {e:?}");
        eprintln!(
            "{name}: {:.0} s, {:.0} MiB",
            e.seconds,
            e.bytes / (1 << 20) as f64
        );
    }
    // Every run of the test suite is a `RunConfig` from these helpers, the paper presets or
    // the configs above; the longest are the paper's runs (`examples/paper`).
    let spec = RunSpec::from_config(&common::hh_config(1000.0, 1.0)).unwrap();
    assert_eq!(
        chaoscope_producer::estimate::run(&spec, &machine).refusal(&machine),
        None
    );
}

#[test]
fn the_json_schema_accepts_every_example_and_refuses_a_typo() {
    // The schema `chaoscope config --schema` prints, checked by a third-party validator (Python's
    // jsonschema, as TOML editors check a file) against every configuration a user is shown:
    // the examples and `run`'s default; and a config with a misspelled key must be refused.
    if !common::python_checks_enabled() {
        return;
    }
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let tmp = tempfile::tempdir().unwrap();
    let out = Command::new(CHAOSCOPE)
        .args(["config", "--schema"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let schema = tmp.path().join("schema.json");
    std::fs::write(&schema, &out.stdout).unwrap();
    let mut valid = vec![root.join("src/cli/hh_chaotic.toml")];
    let mut dirs = vec![root.join("examples")];
    while let Some(dir) = dirs.pop() {
        for e in std::fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                dirs.push(p);
            } else if p.extension().is_some_and(|x| x == "toml")
                && p.file_name().is_some_and(|n| n != "Cargo.toml")
            {
                valid.push(p);
            }
        }
    }
    assert!(valid.len() > 25, "{} configs", valid.len());
    // Typos a user makes: a misspelled key at the top of a table, in a scheme, in [model] (a key
    // of another kind), and a misspelled table.
    let typos = [
        spoil(RUN, "t_final = 1.0", "t_finall = 1.0"),
        spoil(RUN, "d0 = 1e-8", "do = 1e-8"),
        spoil(
            RUN,
            "name = \"henon-heiles\"",
            "name = \"henon-heiles\"\nbeta = 1.0",
        ),
        spoil(MAP, "[map]", "[maps]"),
    ];
    let mut invalid = Vec::new();
    for (i, text) in typos.iter().enumerate() {
        let path = tmp.path().join(format!("typo{i}.toml"));
        std::fs::write(&path, text).unwrap();
        invalid.push(path);
    }
    let out = Command::new("python3")
        .arg(common::python_script("check_schema.py"))
        .arg(&schema)
        .arg("--valid")
        .args(&valid)
        .arg("--invalid")
        .args(&invalid)
        .output()
        .expect("python3 (packages: tests/python/requirements.txt)");
    let report = String::from_utf8_lossy(&out.stdout);
    eprintln!("{report}{}", String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "{report}");
    assert_eq!(
        report.lines().filter(|l| l.starts_with("valid:")).count(),
        valid.len()
    );
    assert_eq!(
        report.lines().filter(|l| l.starts_with("refused:")).count(),
        typos.len()
    );
    // `chaoscope config FILE` validates as `run` and `map` do, without running anything.
    let ok = Command::new(CHAOSCOPE)
        .arg("config")
        .arg(root.join("examples/models/lorenz.toml"))
        .output()
        .unwrap();
    let line = String::from_utf8_lossy(&ok.stdout);
    assert!(
        ok.status.success() && line.contains("\"valid\":true"),
        "{line}"
    );
    assert!(line.contains("a run of a flow of dimension 3"), "{line}");
    let bad = Command::new(CHAOSCOPE)
        .arg("config")
        .arg(&invalid[0])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&bad.stderr);
    assert_eq!(bad.status.code(), Some(1), "{err}");
    assert!(err.contains("integrator.t_finall (line"), "{err}");
}

/// Every file or directory of the repository (relative paths, `/`-separated, directories with a
/// trailing `/`), build outputs and installed packages left out.
fn repository_paths(root: &Path) -> Vec<String> {
    let mut out = Vec::new();
    let mut dirs = vec![root.to_path_buf()];
    while let Some(dir) = dirs.pop() {
        for e in std::fs::read_dir(&dir).unwrap() {
            let p = e.unwrap().path();
            let name = p.file_name().unwrap().to_string_lossy().to_string();
            if matches!(
                name.as_str(),
                "target" | ".git" | "node_modules" | "__pycache__"
            ) {
                continue;
            }
            let rel = p
                .strip_prefix(root)
                .unwrap()
                .to_string_lossy()
                .replace('\\', "/");
            if p.is_dir() {
                out.push(format!("{rel}/"));
                dirs.push(p);
            } else {
                out.push(rel);
            }
        }
    }
    out
}

#[test]
fn architecture_md_maps_the_code_both_ways() {
    // ARCHITECTURE.md is the code map, checked both ways.
    // 1. Every path it names exists: a file that is gone (moved, renamed, merged) sends a reader
    //    nowhere. A path is resolved from the repository root, or within the section's directory
    //    (`### `dynamics/``: `map/` is `dynamics/src/map/`, a bare `engine.rs` some file of that
    //    name below it).
    // 2. Every source file lies under a path it names (the file itself or a directory above
    //    it), so a file added where the map says nothing fails here until the map says where it
    //    belongs. Source files are the code of every language in the repository: `.rs`, `.c`,
    //    `.proto`, `.py`, `.pyi`, `.sh` and `.js`, anywhere outside build outputs and installed
    //    packages (crates' `src/`, `tests/` and `benches/`, `build.rs`, `python/`, `fuzz/`,
    //    `examples/`, the test helpers in other languages). A section heading's own directory
    //    (`### `os/``) and a crate's root directory (one holding a `Cargo.toml`) cover nothing,
    //    or every crate would be covered by its name alone: the map must say where inside it.
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(root.join("ARCHITECTURE.md")).unwrap();
    let paths = repository_paths(root);
    let extensions = [
        ".rs", ".toml", ".md", ".proto", ".py", ".pyi", ".sh", ".c", ".json", ".txt", ".csv",
    ];
    let looks_like_path = |t: &str| {
        !t.is_empty()
            && !t.starts_with('/')
            && t.chars()
                .all(|c| c.is_ascii_alphanumeric() || "_-./".contains(c))
            && (extensions.iter().any(|e| t.ends_with(e)) || (t.ends_with('/') && t.len() > 1))
    };
    let (mut section, mut checked, mut missing) = (String::new(), 0, Vec::new());
    // The repository paths the map's names resolve to, headings left out.
    let mut named: Vec<&str> = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let heading = line.starts_with("### ");
        if let Some(rest) = line.strip_prefix("### ") {
            // `### `dynamics/` (chaoscope-dynamics)`: paths below are the crate's.
            let name = rest.strip_prefix('`').and_then(|r| r.split('`').next());
            section = name.filter(|n| n.ends_with('/')).unwrap_or("").to_string();
        } else if line.starts_with("## ") {
            section.clear();
        }
        for token in line.split('`').skip(1).step_by(2) {
            if !looks_like_path(token) {
                continue;
            }
            checked += 1;
            let matches: Vec<&str> = paths
                .iter()
                .map(String::as_str)
                .filter(|p| {
                    *p == token
                        || p.strip_prefix(section.as_str()).is_some_and(|inner| {
                            inner == token || inner.ends_with(&format!("/{token}"))
                        })
                })
                .collect();
            if matches.is_empty() {
                missing.push(format!("line {}: `{token}` (section `{section}`)", n + 1));
            }
            let crate_root =
                |p: &&str| p.ends_with('/') && paths.contains(&format!("{p}Cargo.toml"));
            if !heading {
                named.extend(matches.into_iter().filter(|p| !crate_root(p)));
            }
        }
    }
    assert!(
        checked > 80,
        "only {checked} paths found in ARCHITECTURE.md"
    );
    assert!(
        missing.is_empty(),
        "ARCHITECTURE.md names {} paths that do not exist:\n{}",
        missing.len(),
        missing.join("\n")
    );
    let sources = [".rs", ".c", ".proto", ".py", ".pyi", ".sh", ".js"];
    let uncovered: Vec<&String> = paths
        .iter()
        .filter(|p| !p.ends_with('/') && sources.iter().any(|e| p.ends_with(e)))
        .filter(|p| {
            !named
                .iter()
                .any(|n| *n == p.as_str() || (n.ends_with('/') && p.starts_with(n)))
        })
        .collect();
    // Guards against a walk that found nothing (the check above would then pass vacuously):
    // the workspace holds well over 200 source files.
    let total = paths
        .iter()
        .filter(|p| sources.iter().any(|e| p.ends_with(e)))
        .count();
    assert!(
        total > 200,
        "only {total} source files found under {root:?}"
    );
    assert!(
        uncovered.is_empty(),
        "{} source files lie under no path ARCHITECTURE.md names (name the file or its \
         directory in the code map):\n{}",
        uncovered.len(),
        uncovered
            .iter()
            .map(|p| p.as_str())
            .collect::<Vec<_>>()
            .join("\n")
    );
}

/// The crates' normal (non-dev, non-build) dependency graph, by package name, as
/// `cargo metadata` resolves it from the lock file for this host (no build, no network: the
/// crates of other platforms, which a build here never downloads, are left out).
fn normal_dependencies(root: &Path) -> (Vec<String>, BTreeMap<String, BTreeSet<String>>) {
    let rustc = std::env::var_os("RUSTC").unwrap_or_else(|| "rustc".into());
    let version = Command::new(rustc).arg("-vV").output().unwrap();
    let version = String::from_utf8_lossy(&version.stdout);
    let host = version
        .lines()
        .find_map(|l| l.strip_prefix("host: "))
        .expect("rustc -vV names the host")
        .trim()
        .to_owned();
    let out = Command::new(env!("CARGO"))
        .args([
            "metadata",
            "--offline",
            "--format-version",
            "1",
            "--filter-platform",
        ])
        .arg(&host)
        .current_dir(root)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "cargo metadata: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let meta: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let name_of: BTreeMap<&str, &str> = meta["packages"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| (p["id"].as_str().unwrap(), p["name"].as_str().unwrap()))
        .collect();
    let members: Vec<String> = meta["workspace_members"]
        .as_array()
        .unwrap()
        .iter()
        .map(|id| name_of[id.as_str().unwrap()].to_string())
        .collect();
    let mut graph: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for node in meta["resolve"]["nodes"].as_array().unwrap() {
        let deps = node["deps"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|d| {
                d["dep_kinds"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .any(|k| k["kind"].is_null())
            })
            .map(|d| name_of[d["pkg"].as_str().unwrap()].to_string());
        graph
            .entry(name_of[node["id"].as_str().unwrap()].to_string())
            .or_default()
            .extend(deps);
    }
    (members, graph)
}

/// Every package `from` reaches through normal dependencies, never entering `stop`.
fn reached(
    graph: &BTreeMap<String, BTreeSet<String>>,
    from: &str,
    stop: &[&str],
) -> BTreeSet<String> {
    let (mut seen, mut todo) = (BTreeSet::new(), vec![from.to_string()]);
    while let Some(p) = todo.pop() {
        for d in graph.get(&p).into_iter().flatten() {
            if !stop.contains(&d.as_str()) && seen.insert(d.clone()) {
                todo.push(d.clone());
            }
        }
    }
    seen
}

#[test]
fn iceoryx2_is_reached_only_from_the_bus_and_the_processes_around_it() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let (members, graph) = normal_dependencies(root);
    let is_iceoryx2 = |p: &String| p == "iceoryx2" || p.starts_with("iceoryx2-");
    // The bus, and the processes that publish (producer; the library route's example, which
    // publishes through it), record or subscribe (recorder, the binary's monitors, Python's).
    let on_the_bus = [
        "chaoscope-bus",
        "chaoscope-producer",
        "chaoscope-recorder",
        "chaoscope",
        "chaoscope-python",
        "chaoscope-example-custom-model",
    ];
    // Numerics, files and analysis: the analysis is fed samples by the file reader, or by a
    // live subscription that lives with the bus.
    let off_the_bus = [
        "chaoscope-os",
        "chaoscope-schemas",
        "chaoscope-indicators",
        "chaoscope-expr",
        "chaoscope-dynamics",
        "chaoscope-files",
        "chaoscope-analyzer",
        "chaoscope-app",
        // Times the numerics in process, and whole runs as child processes.
        "chaoscope-bench",
    ];
    let mut listed: Vec<&str> = on_the_bus.iter().chain(&off_the_bus).copied().collect();
    listed.sort_unstable();
    let mut all: Vec<&str> = members.iter().map(String::as_str).collect();
    all.sort_unstable();
    assert_eq!(listed, all, "every workspace crate is on or off the bus");
    for m in on_the_bus {
        assert!(
            reached(&graph, m, &[]).iter().any(is_iceoryx2),
            "{m} is on the bus and reaches no iceoryx2: the list above is stale"
        );
    }
    for m in off_the_bus {
        let reach = reached(&graph, m, &[]);
        let bus: Vec<&String> = reach.iter().filter(|p| is_iceoryx2(p)).collect();
        assert!(bus.is_empty(), "{m} reaches {bus:?}");
        for p in ["chaoscope-bus", "indicatif"] {
            assert!(!reach.contains(p), "{m} reaches {p}");
        }
    }
    // prost is the file format: `schemas` (the messages), `files` and `analyzer` (which read
    // and write them) use it directly, as the bus's processes do. The numerics do not: the
    // dynamics and replay reach it through those crates alone, and os, indicators and expr
    // not at all.
    for m in ["chaoscope-dynamics", "chaoscope-app"] {
        let beyond_formats = reached(
            &graph,
            m,
            &["chaoscope-schemas", "chaoscope-files", "chaoscope-analyzer"],
        );
        assert!(!beyond_formats.contains("prost"), "{m} depends on prost");
    }
    for m in ["chaoscope-os", "chaoscope-indicators", "chaoscope-expr"] {
        assert!(
            !reached(&graph, m, &[]).contains("prost"),
            "{m} reaches prost"
        );
    }
}

#[test]
fn crate_dependencies_are_the_architecture_md_layering() {
    // The code map's table (`crate    what it depends on`), read in order: each crate depends on
    // exactly the workspace crates its line names, every one of them on an earlier line, so
    // dependencies point one way.
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(root.join("ARCHITECTURE.md")).unwrap();
    let (members, graph) = normal_dependencies(root);
    let map = text.split("## Code map").nth(1).unwrap();
    let table = map.split("```").nth(1).unwrap();
    let package = |n: &str| match n {
        "chaoscope (binary)" => "chaoscope".to_string(),
        "python" => "chaoscope-python".to_string(),
        n => format!("chaoscope-{n}"),
    };
    let mut earlier: Vec<String> = Vec::new();
    let mut layered = BTreeSet::new();
    for line in table.lines().filter(|l| !l.trim().is_empty()) {
        let (names, deps) = line.split_once("  ").unwrap();
        let deps = deps.trim();
        let crates: Vec<String> = names.split(", ").map(package).collect();
        for c in &crates {
            let actual: BTreeSet<String> = graph[c.as_str()]
                .iter()
                .filter(|d| members.contains(d))
                .cloned()
                .collect();
            let named: BTreeSet<String> = match deps {
                "no chaoscope dependency" => BTreeSet::new(),
                // The shells: everything above, whatever they use of it.
                "all of them" => actual.clone(),
                deps => deps.split(", ").map(package).collect(),
            };
            assert_eq!(
                actual, named,
                "{c}: ARCHITECTURE.md's layering says otherwise"
            );
            for d in &actual {
                assert!(
                    earlier.contains(d),
                    "{c} depends on {d}, which is not above it"
                );
            }
            layered.insert(c.clone());
        }
        earlier.extend(crates);
    }
    for m in &members {
        assert!(
            layered.contains(m) || m == "chaoscope-example-custom-model",
            "{m} is missing from ARCHITECTURE.md's layering"
        );
    }
}

/// `chaoscope run` of `config` in `dir` with its address space limited to `limit` bytes (set in
/// the child before exec, as `ulimit -v`); its exit code (`None`: killed by a signal, such as
/// the abort of a failed allocation) and stderr. Killed after a minute.
fn run_limited(config: &str, dir: &Path, limit: u64) -> (Option<i32>, String) {
    use std::os::unix::process::CommandExt;
    let path = dir.join("limited.toml");
    std::fs::write(&path, config).unwrap();
    let mut command = Command::new(CHAOSCOPE);
    command
        .args(["run", path.to_str().unwrap(), "--out"])
        .arg(dir.join("limited.mcap"))
        .arg("--force")
        .current_dir(dir)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    // SAFETY: setrlimit(2) is async-signal-safe; nothing else runs between fork and exec.
    unsafe {
        command.pre_exec(move || {
            let rl = libc::rlimit {
                rlim_cur: limit,
                rlim_max: limit,
            };
            if libc::setrlimit(libc::RLIMIT_AS, &rl) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    let mut child = command.spawn().unwrap();
    let start = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if start.elapsed() > Duration::from_secs(60) {
            let _ = child.kill();
            let _ = child.wait();
            panic!("{config}: still running after a minute");
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let mut stderr = String::new();
    std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut stderr).unwrap();
    (status.code(), stderr)
}

/// A potential of two degrees of freedom written as `potential`, to t = 1.
fn potential_run(potential: &str) -> String {
    format!(
        "[run]\nname = \"{}\"\n[model]\nname = \"potential\"\nn = 2\npotential = \"{potential}\"\n\
         [orbit]\nq = [0.1, 0.0]\np = [0.0, 0.1]\n\
         [integrator]\nmethod = \"aba864\"\nh = 0.01\nt_final = 1.0\n\
         [deviations]\nk = 2\nsets = 1\nseed = 1\n\
         [[scheme]]\nname = \"vm\"\nmethod = \"vm\"\nd0 = 1e-8\ntau = 0.1\n",
        unique_run("blowup")
    )
}

/// Expressions whose size is set by a few bytes (sum bounds, nested sums) are refused before
/// they allocate what they describe: under a 512 MiB address-space limit the refusal is one line
/// and exit 1 (before: the 36-byte sum took 1.1 GB and aborted under such a limit; the nested
/// sum, 4 million nodes, went on to differentiate and compile them), while a valid potential
/// runs under the same limit.
#[test]
fn expression_blow_ups_are_refused_under_a_memory_limit() {
    const LIMIT: u64 = 512 << 20;
    let dir = tempfile::tempdir().unwrap();
    for (potential, said) in [
        (
            "sum(i = 1..100000000, q1^2)",
            "sum over 100000000 terms: an expression may expand to at most 2000000 graph nodes",
        ),
        (
            "sum(i = 1..2000, sum(j = 1..2000, q1*i*j))",
            "the expression expands to more than 2000000 graph nodes",
        ),
    ] {
        let (code, stderr) = run_limited(&potential_run(potential), dir.path(), LIMIT);
        let lines: Vec<&str> = stderr.lines().collect();
        assert_eq!(code, Some(1), "{potential}: {stderr}");
        // One line says it all; the expression and a caret under it follow, indented.
        assert!(
            lines[0].contains("model.potential")
                && lines[0].contains(said)
                && lines[1..].iter().all(|l| l.starts_with("  ")),
            "{potential}: {stderr}"
        );
    }
    let (code, stderr) = run_limited(
        &potential_run("(q1^2 + q2^2)/2 + q1^2*q2 - q2^3/3"),
        dir.path(),
        LIMIT,
    );
    assert_eq!(code, Some(0), "a valid potential under the limit: {stderr}");
}

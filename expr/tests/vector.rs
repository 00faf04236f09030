//! The compiled vector function (a flow's `rhs`, a map's `next`) against the reference evaluator
//! of its own graph (bit for bit, scalar and lanes) and against derivatives written by hand
//! (Lorenz, Henon map, the standard map: exact formulas, so the tolerance is rounding only).

use std::collections::BTreeMap;

use chaoscope_expr::{
    Boundary, Evaluator, ParamValue, VectorDefinition, VectorError, VectorFunction,
};

fn definition(key: &str, components: &[&str], params: &[(&str, ParamValue)]) -> VectorDefinition {
    VectorDefinition {
        key: key.to_string(),
        components: components.iter().map(|c| c.to_string()).collect(),
        params: params
            .iter()
            .map(|(n, v)| (n.to_string(), v.clone()))
            .collect::<BTreeMap<_, _>>(),
        boundary: Boundary::Fixed,
        tables: Vec::new(),
        time: true,
    }
}

fn lorenz() -> VectorFunction {
    VectorFunction::new(definition(
        "rhs",
        &[
            "sigma * (x2 - x1)",
            "x1 * (rho - x3) - x2",
            "x1 * x2 - beta * x3",
        ],
        &[
            ("sigma", ParamValue::Scalar(10.0)),
            ("rho", ParamValue::Scalar(28.0)),
            ("beta", ParamValue::Scalar(8.0 / 3.0)),
        ],
    ))
    .unwrap()
}

/// Deterministic pseudo-random numbers in [-1, 1) (splitmix64).
fn uniform(n: usize, seed: u64) -> Vec<f64> {
    let mut s = seed;
    (0..n)
        .map(|_| {
            s = s.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = s;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^= z >> 31;
            2.0 * ((z >> 11) as f64 / (1u64 << 53) as f64) - 1.0
        })
        .collect()
}

fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

/// Every compiled form (scalar, lanes for several lane counts, shared reference for `J v`)
/// gives the reference evaluator's bits.
fn check_bit_identical(f: &VectorFunction, scale: f64) {
    let d = f.dim();
    let (g, values, tangent, divergence) = f.graph();
    let mut ev = Evaluator::new();
    for lanes in [1usize, 2, 3, 4, 5, 8, 13] {
        let xs: Vec<Vec<f64>> = (0..lanes)
            .map(|l| uniform(d, 7 + l as u64).iter().map(|u| scale * u).collect())
            .collect();
        let vs: Vec<Vec<f64>> = (0..lanes).map(|l| uniform(d, 99 + l as u64)).collect();
        let soa = |rows: &[Vec<f64>]| -> Vec<f64> {
            (0..d)
                .flat_map(|i| rows.iter().map(move |r| r[i]))
                .collect()
        };
        let (x_soa, v_soa) = (soa(&xs), soa(&vs));
        let mut f_lanes = vec![0.0; d * lanes];
        f.value_lanes(&x_soa, &mut f_lanes, lanes);
        let mut div_lanes = vec![0.0; lanes];
        f.divergence_lanes(&x_soa, &mut div_lanes, lanes);
        // J v around the first lane's state, shared by every direction.
        let mut jv_lanes = vec![0.0; d * lanes];
        assert!(f.tangent_lanes(&xs[0], &v_soa, &mut jv_lanes, lanes));
        for l in 0..lanes {
            let mut want = vec![0.0; d];
            ev.eval(g, &[&xs[l]], values, &mut want);
            let mut got = vec![0.0; d];
            f.value(&xs[l], &mut got);
            assert_eq!(bits(&got), bits(&want), "F scalar, lane {l}");
            let lane: Vec<f64> = (0..d).map(|i| f_lanes[i * lanes + l]).collect();
            assert_eq!(bits(&lane), bits(&want), "F lanes {lanes}, lane {l}");

            let mut want_div = [0.0];
            ev.eval(g, &[&xs[l]], &[divergence], &mut want_div);
            assert_eq!(f.divergence(&xs[l]).to_bits(), want_div[0].to_bits());
            assert_eq!(div_lanes[l].to_bits(), want_div[0].to_bits());

            ev.eval(g, &[&xs[0], &vs[l]], tangent, &mut want);
            assert!(f.tangent(&xs[0], &vs[l], &mut got));
            assert_eq!(bits(&got), bits(&want), "J v scalar, lane {l}");
            let lane: Vec<f64> = (0..d).map(|i| jv_lanes[i * lanes + l]).collect();
            assert_eq!(bits(&lane), bits(&want), "J v lanes {lanes}, lane {l}");
        }
    }
}

#[test]
fn compiled_forms_match_the_reference_evaluator_bit_for_bit() {
    check_bit_identical(&lorenz(), 20.0);
    // Transcendental calls, parameters per component, a lattice sum and a coupling through x[i].
    let chain = VectorFunction::new(definition(
        "next",
        &[
            "x1 + k[1] * sin(x2) / (2 * pi)",
            "x2 + x1 + exp(-x3^2) * cos(x4)",
            "x3 + sum(i = 1..N, tanh(x[i])) / N",
            "x4 + atan(x1 / (1 + x2^2)) - log(2 + x3^2)",
        ],
        &[("k", ParamValue::Array(vec![1.0, 2.0, 3.0, 0.5]))],
    ))
    .unwrap();
    check_bit_identical(&chain, 3.0);
}

/// Lorenz: `J` and `tr J = -(sigma + 1 + beta)` written by hand. The Jacobian's entries are
/// single products (`x1 * v2`, `(rho - x3) * v1`), so they agree to rounding of a few
/// operations: 4 ulp of the largest term.
#[test]
fn lorenz_jacobian_and_divergence_by_hand() {
    let f = lorenz();
    assert_eq!(f.dim(), 3);
    assert!(f.has_tangent() && f.no_tangent_reason().is_none());
    let (s, r, b) = (10.0, 28.0, 8.0 / 3.0);
    for seed in 0..20 {
        let x: Vec<f64> = uniform(3, seed).iter().map(|u| 30.0 * u).collect();
        let v = uniform(3, seed + 1000);
        let mut jv = [0.0; 3];
        assert!(f.tangent(&x, &v, &mut jv));
        let want = [
            s * (v[1] - v[0]),
            (r - x[2]) * v[0] - v[1] - x[0] * v[2],
            x[1] * v[0] + x[0] * v[1] - b * v[2],
        ];
        for i in 0..3 {
            assert!(
                (jv[i] - want[i]).abs() <= 4.0 * f64::EPSILON * 30.0 * 30.0,
                "J v [{i}]: {} vs {}",
                jv[i],
                want[i]
            );
        }
        // Several vectors in one call: each the bits of its own call (the Runge-Kutta tangent
        // step applies a stage's Jacobian to all its vectors this way).
        let vs = uniform(9, seed + 2000);
        let mut all = [0.0; 9];
        assert!(f.tangents_at(&x, 0.0, &vs, &mut all));
        for (v, got) in vs.chunks_exact(3).zip(all.chunks_exact(3)) {
            let mut one = [0.0; 3];
            assert!(f.tangent(&x, v, &mut one));
            assert_eq!(bits(got), bits(&one));
        }
        // The diagonal is constant: -sigma, -1, -beta, summed in that order.
        assert_eq!(f.divergence(&x), (-s - 1.0) - b);
        let mut fx = [0.0; 3];
        f.value(&x, &mut fx);
        assert_eq!(fx[0], s * (x[1] - x[0]));
    }
}

/// Henon map: `det J = -b` everywhere; the divergence is `-2 a x1` (the trace).
#[test]
fn henon_map_jacobian() {
    let f = VectorFunction::new(definition(
        "next",
        &["1 - a * x1^2 + x2", "b * x1"],
        &[
            ("a", ParamValue::Scalar(1.4)),
            ("b", ParamValue::Scalar(0.3)),
        ],
    ))
    .unwrap();
    for seed in 0..10 {
        let x = uniform(2, seed);
        let mut c1 = [0.0; 2];
        let mut c2 = [0.0; 2];
        assert!(f.tangent(&x, &[1.0, 0.0], &mut c1));
        assert!(f.tangent(&x, &[0.0, 1.0], &mut c2));
        assert_eq!(c1, [-2.8 * x[0], 0.3]);
        assert_eq!(c2, [1.0, 0.0]);
        assert_eq!(c1[0] * c2[1] - c2[0] * c1[1], -0.3);
        assert_eq!(f.divergence(&x), -2.8 * x[0]);
    }
}

#[test]
fn errors_name_the_component_with_line_column_and_caret() {
    let e =
        VectorFunction::new(definition("next", &["x1 + x2", "x1 +\n  sinn(x2)"], &[])).unwrap_err();
    let VectorError::Component {
        component, error, ..
    } = &e
    else {
        panic!("{e}")
    };
    assert_eq!((*component, error.line, error.column), (2, 2, 3));
    let text = e.to_string();
    assert!(
        text.starts_with("next[2]: line 2, column 3: unknown function 'sinn'"),
        "{text}"
    );
    assert!(text.ends_with("    sinn(x2)\n    ^^^^"), "{text}");

    // A variable beyond the dimension is a typo, named with the component.
    let e = VectorFunction::new(definition("rhs", &["x3", "x1"], &[])).unwrap_err();
    assert!(
        e.to_string().starts_with("rhs[1]: line 1, column 1:"),
        "{e}"
    );
    assert!(e.to_string().contains("x3"), "{e}");

    let e = VectorFunction::new(definition("rhs", &[], &[])).unwrap_err();
    assert_eq!(e.to_string(), "rhs needs at least one component");
}

#[test]
fn no_tangent_names_operation_position_and_component() {
    let f = VectorFunction::new(definition("next", &["x1 + x2", "x2 - abs(x1)"], &[])).unwrap();
    assert!(!f.has_tangent());
    let reason = f.no_tangent_reason().unwrap();
    assert_eq!(
        reason,
        "the variational method (vm) needs continuous first derivatives, but 'abs' at line 1, \
         column 6 of next[2] has a kink (continuous, first derivative jumps); use mpm"
    );
    let mut out = [7.0; 2];
    assert!(!f.tangent(&[0.0, 0.0], &[1.0, 0.0], &mut out));
    assert_eq!(out, [7.0; 2]);
    // A map is still a map: F evaluates, and the divergence is defined off the kink.
    let mut fx = [0.0; 2];
    f.value(&[-2.0, 1.0], &mut fx);
    assert_eq!(fx, [-1.0, -1.0]);
    assert_eq!(f.divergence(&[-2.0, 1.0]), 2.0);
    // Smooth per component: the first has no limit.
    assert!(f.smoothness()[0].is_smooth() && !f.smoothness()[1].is_smooth());
}

#[test]
fn diagnosis_names_the_operation_and_component() {
    let f = VectorFunction::new(definition("next", &["x1 + 1", "log(x1) + x2"], &[])).unwrap();
    assert_eq!(f.diagnose_non_finite(&[1.0, 2.0]), None);
    let d = f.diagnose_non_finite(&[-1.0, 2.0]).unwrap();
    assert_eq!(
        d,
        "'log' at line 1, column 1 of next[2] gave NaN in next[2] (x = [-1.0, 2.0])"
    );
}

/// Lane parameters (a map's parameter axes): each lane's own value, read after the state's
/// coordinates, gives the bits of the function compiled with that value as a constant (value,
/// divergence and lanes; the Jacobian-vector product around a shared state), the expressions
/// being ones where the constant folds with nothing; a function of lane parameters alone
/// (`sqrt(K)`, `abs(c)`) limits no derivative with respect to the variables, so VM stays
/// allowed; and the non-finite diagnosis reads the parameters.
#[test]
fn lane_parameters_give_the_bits_of_the_folded_constants() {
    use chaoscope_expr::vector::ARG_PARAMS;
    let components = [
        "x1 + x2 + K * sin(x1) * sqrt(K)",
        "x2 + c * K * sin(x1) + abs(c)",
    ];
    let lane = |index, min, max| ParamValue::Lane {
        arg: ARG_PARAMS,
        index,
        min,
        max,
    };
    let by_lane = VectorFunction::new(definition(
        "next",
        &components,
        &[("K", lane(0, 0.0, 2.0)), ("c", lane(1, -1.0, 1.0))],
    ))
    .unwrap();
    assert_eq!(
        (by_lane.dim(), by_lane.lane_params(), by_lane.state_len()),
        (2, 2, 4)
    );
    assert!(by_lane.has_tangent(), "{:?}", by_lane.no_tangent_reason());
    let points = [
        [0.3, -1.2, 0.7, 0.25],
        [2.5, 0.4, 1.9, -0.75],
        [6.0, 3.0, 0.0, 1.0],
    ];
    let lanes = points.len();
    let mut soa = vec![0.0; 4 * lanes];
    for (l, p) in points.iter().enumerate() {
        for (r, v) in p.iter().enumerate() {
            soa[r * lanes + l] = *v;
        }
    }
    let mut out_lanes = vec![0.0; 2 * lanes];
    by_lane.value_lanes(&soa, &mut out_lanes, lanes);
    let mut div_lanes = vec![0.0; lanes];
    by_lane.divergence_lanes(&soa, &mut div_lanes, lanes);
    for (l, p) in points.iter().enumerate() {
        let folded = VectorFunction::new(definition(
            "next",
            &components,
            &[
                ("K", ParamValue::Scalar(p[2])),
                ("c", ParamValue::Scalar(p[3])),
            ],
        ))
        .unwrap();
        let (mut want, mut got) = ([0.0; 2], [0.0; 2]);
        folded.value(&p[..2], &mut want);
        by_lane.value(p, &mut got);
        assert_eq!(bits(&got), bits(&want), "value at {p:?}");
        assert_eq!(
            bits(&[out_lanes[l], out_lanes[lanes + l]]),
            bits(&want),
            "lane {l}"
        );
        assert_eq!(
            by_lane.divergence(p).to_bits(),
            folded.divergence(&p[..2]).to_bits()
        );
        assert_eq!(div_lanes[l].to_bits(), folded.divergence(&p[..2]).to_bits());
        // J v for three directions around this point's state.
        let v = [1.0, 0.0, 0.5, -2.0, 0.25, 3.0];
        let (mut want_jv, mut got_jv) = (vec![0.0; 6], vec![0.0; 6]);
        assert!(folded.tangent_lanes(&p[..2], &v, &mut want_jv, 3));
        assert!(by_lane.tangent_lanes(p, &v, &mut got_jv, 3));
        assert_eq!(bits(&got_jv), bits(&want_jv), "J v at {p:?}");
    }
    // A parameter that makes the value non-finite is named with the state it came from.
    let log = VectorFunction::new(definition(
        "next",
        &["x1 + log(K)", "x2"],
        &[("K", lane(0, 0.0, 1.0))],
    ))
    .unwrap();
    let why = log.diagnose_non_finite(&[1.0, 2.0, -1.0]).unwrap();
    assert!(why.contains("'log'") && why.contains("next[1]"), "{why}");
    assert!(log.diagnose_non_finite(&[1.0, 2.0, 0.5]).is_none());
}

/// A right-hand side that reads the time `t`: every compiled form (scalar `*_at`, lanes at one
/// shared time) gives the reference evaluator's bits with the time as argument 2, at several
/// times; `t` is a built-in there (a parameter of that name is an error naming it), and an
/// ordinary name where the definition has no time (a map's `next`).
#[test]
fn time_is_an_argument_of_every_compiled_form() {
    let f = VectorFunction::new(definition(
        "rhs",
        &[
            "x2",
            "-0.3 * x2 + x1 - x1^3 + gamma * cos(1.2 * t)",
            "x1 * sin(t) - t * x3",
        ],
        &[("gamma", ParamValue::Scalar(0.5))],
    ))
    .unwrap();
    assert!(f.reads_time());
    assert!(!lorenz().reads_time());
    let (g, values, tangent, divergence) = f.graph();
    let mut ev = Evaluator::new();
    let d = f.dim();
    for (k, t) in [0.0, 0.37, 12.5, -3.0].into_iter().enumerate() {
        let time = [t];
        let lanes = 5;
        let xs: Vec<Vec<f64>> = (0..lanes)
            .map(|l| uniform(d, 11 + l as u64 + k as u64))
            .collect();
        let v = uniform(d, 5);
        let soa: Vec<f64> = (0..d).flat_map(|i| xs.iter().map(move |r| r[i])).collect();
        let mut f_lanes = vec![0.0; d * lanes];
        f.value_lanes_at(&soa, t, &mut f_lanes, lanes);
        for (l, x) in xs.iter().enumerate() {
            let mut want = vec![0.0; d];
            ev.eval(g, &[x, &[], &time], values, &mut want);
            let mut got = vec![0.0; d];
            f.value_at(x, t, &mut got);
            assert_eq!(bits(&got), bits(&want), "F at t = {t}");
            let lane: Vec<f64> = (0..d).map(|i| f_lanes[i * lanes + l]).collect();
            assert_eq!(bits(&lane), bits(&want), "F lanes at t = {t}, lane {l}");
            ev.eval(g, &[x, &v, &time], tangent, &mut want);
            assert!(f.tangent_at(x, t, &v, &mut got));
            assert_eq!(bits(&got), bits(&want), "J v at t = {t}");
            let mut div = [0.0];
            ev.eval(g, &[x, &[], &time], &[divergence], &mut div);
            assert_eq!(f.divergence_at(x, t).to_bits(), div[0].to_bits());
            // The time enters: dF3/dx3 = -t.
            assert_eq!(div[0], -0.3 - t);
        }
    }
    let clash = VectorFunction::new(definition(
        "rhs",
        &["t * x1"],
        &[("t", ParamValue::Scalar(1.0))],
    ))
    .unwrap_err()
    .to_string();
    assert!(
        clash.contains("parameter 't' has the name of the time"),
        "{clash}"
    );
    let mut map = definition("next", &["t * x1"], &[]);
    map.time = false;
    let unknown = VectorFunction::new(map).unwrap_err().to_string();
    assert!(unknown.contains("unknown name 't'"), "{unknown}");
}

/// Time and lane parameters together (a parameter axis over a non-autonomous flow): the two
/// are distinct argument arrays (`ARG_T` shared by the lanes, `ARG_PARAMS` per lane), so at
/// each time every lane gives the bits of the function compiled with its parameter as a
/// constant, evaluated at that time, in every compiled form.
#[test]
fn time_and_lane_parameters_are_distinct_arguments() {
    use chaoscope_expr::vector::{ARG_PARAMS, ARG_T};
    assert_ne!(ARG_T, ARG_PARAMS);
    let components = ["x2", "-0.3 * x2 + x1 - x1^3 + gamma * cos(1.2 * t)"];
    let by_lane = VectorFunction::new(definition(
        "rhs",
        &components,
        &[(
            "gamma",
            ParamValue::Lane {
                arg: ARG_PARAMS,
                index: 0,
                min: 0.0,
                max: 1.0,
            },
        )],
    ))
    .unwrap();
    assert!(by_lane.reads_time());
    assert_eq!(by_lane.state_len(), 3);
    let points = [[0.3, -1.2, 0.1], [2.5, 0.4, 0.9], [-1.0, 0.5, 0.45]];
    let lanes = points.len();
    let soa: Vec<f64> = (0..3)
        .flat_map(|r| points.iter().map(move |p| p[r]))
        .collect();
    for t in [0.0, 0.37, 12.5] {
        let mut out_lanes = vec![0.0; 2 * lanes];
        by_lane.value_lanes_at(&soa, t, &mut out_lanes, lanes);
        let mut div_lanes = vec![0.0; lanes];
        by_lane.divergence_lanes_at(&soa, t, &mut div_lanes, lanes);
        for (l, p) in points.iter().enumerate() {
            let folded = VectorFunction::new(definition(
                "rhs",
                &components,
                &[("gamma", ParamValue::Scalar(p[2]))],
            ))
            .unwrap();
            let (mut want, mut got) = ([0.0; 2], [0.0; 2]);
            folded.value_at(&p[..2], t, &mut want);
            by_lane.value_at(p, t, &mut got);
            assert_eq!(bits(&got), bits(&want), "value at {p:?}, t = {t}");
            assert_eq!(
                bits(&[out_lanes[l], out_lanes[lanes + l]]),
                bits(&want),
                "lane {l}, t = {t}"
            );
            // The forcing moves the value with t (when gamma is not 0): the time is read.
            let mut at_zero = [0.0; 2];
            folded.value_at(&p[..2], 0.0, &mut at_zero);
            if t != 0.0 {
                assert_ne!(bits(&at_zero), bits(&want), "t = {t} is read");
            }
            assert_eq!(
                div_lanes[l].to_bits(),
                folded.divergence_at(&p[..2], t).to_bits()
            );
            let v = [1.0, 0.0, 0.5, -2.0];
            let (mut want_jv, mut got_jv) = (vec![0.0; 4], vec![0.0; 4]);
            assert!(folded.tangent_lanes_at(&p[..2], t, &v, &mut want_jv, 2));
            assert!(by_lane.tangent_lanes_at(p, t, &v, &mut got_jv, 2));
            assert_eq!(bits(&got_jv), bits(&want_jv), "J v at {p:?}, t = {t}");
        }
    }
}

//! The recording's `F_object` (the simulated object's own force) beside `F_true` (the felt
//! force): on a hand run (shadow) they differ by the bench's friction and mass, in the file as
//! in memory; reproduction has no object of the bench's own (NaN); a replay passes it through.

mod common;

use rt_loop::config::{BoardKind, ExperimentKind};
use rt_loop::record::read::read_columns;

#[test]
fn a_hand_run_records_the_objects_force_beside_the_felt_one() {
    let dir = common::tmpdir("object-force");
    let path = dir.join("shadow.csv");
    let mut cfg = common::short_cfg(1, 1.0, 0.0);
    cfg.hand.repeats = 1;
    cfg.experiment = ExperimentKind::Shadow;
    cfg.record = Some(path.clone());
    assert!(rt_loop::run::run(&cfg, None, None).unwrap().ok());
    let c = read_columns(&path, &["F_true", "F_object", "velocity"]).unwrap();
    let (felt, object, v) = (&c[0], &c[1], &c[2]);
    assert!(object.iter().all(|f| f.is_finite()));
    let peak = object.iter().cloned().fold(0.0, f64::max);
    // where the probe rests pressed (a hold): the felt force carries the friction's share
    // (and what the transparent motor leaves), which an object-only model does not predict
    let mut rest: Vec<f64> = (0..v.len())
        .filter(|&i| v[i].abs() < 1e-4 && felt[i] > 1.0)
        .map(|i| (felt[i] - object[i]).abs())
        .collect();
    rest.sort_by(f64::total_cmp);
    let median = rest.get(rest.len() / 2).copied().unwrap_or(0.0);
    eprintln!(
        "shadow: peak object force {peak:.2} N; {} pressed rows at rest, |felt - object| median {median:.3} N",
        rest.len()
    );
    assert!(peak > 2.0);
    assert!(rest.len() > 1000, "{}", rest.len());
    assert!(median > 0.3 && median < 2.0, "{median}");

    // replaying the recording carries the column through
    let mut rp = cfg.clone();
    rp.board = BoardKind::Replay;
    rp.replay = Some(path.clone());
    rp.record = Some(dir.join("replayed.parquet"));
    assert!(rt_loop::run::run(&rp, None, None).unwrap().ok());
    let back = read_columns(&dir.join("replayed.parquet"), &["F_object"]).unwrap();
    assert_eq!(back[0].len(), object.len());
    assert!(back[0]
        .iter()
        .zip(object)
        .all(|(a, b)| a.to_bits() == b.to_bits()));

    // reproduction: the object is the rendered model, not the bench's: NaN
    let mut re = cfg.clone();
    re.experiment = ExperimentKind::Reproduction;
    re.record = None;
    let (rows, _) = common::run_rows(&re);
    assert!(rows
        .iter()
        .all(|r| r.f_object.is_nan() && r.f_true.is_finite()));
}

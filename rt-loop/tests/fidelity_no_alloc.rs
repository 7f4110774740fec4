//! The issue-11 additions on the real-time path allocate nothing: the oracle model and the
//! friction-compensated observer, inside `Rig::step` of a reproduction run, counted by a global
//! allocator (one test function: the counter is global).

#[path = "support/alloc_count.rs"]
mod alloc_count;

use rt_loop::config::{ExperimentKind, RunConfig};
use rt_loop::control::friction::Friction;
use rt_loop::object::material::Material;
use rt_loop::object::oracle::OracleModel;

#[test]
fn oracle_reproduction_with_friction_compensation_allocates_nothing() {
    let material = concat!(env!("CARGO_MANIFEST_DIR"), "/../materials/sponge.toml");
    let mut cfg = RunConfig {
        experiment: ExperimentKind::Reproduction,
        material: material.into(),
        ..RunConfig::default()
    };
    cfg.params.friction = Friction {
        coulomb_n: 0.88,
        viscous: 4.8,
        ..Friction::default()
    };
    let (m, _) = Material::load(&cfg.material).unwrap();
    let oracle = OracleModel::new(&m, cfg.rate_hz, 1.0);
    let mut rig = rt_loop::run::build_rig(&cfg, Some(Box::new(oracle))).unwrap();
    alloc_count::start();
    let mut pushed = 0.0f64;
    let mut done = 0;
    // 3 s: the hand presses into the virtual sponge, so the oracle and the compensation work
    for _ in 0..30_000 {
        match rig.step() {
            Ok(row) => {
                pushed = pushed.max(row.f_pred);
                done += 1;
            }
            Err(_) => break,
        }
    }
    let n = alloc_count::stop();
    assert_eq!(done, 30_000);
    assert_eq!(n, 0, "the oracle reproduction step allocated {n} times");
    assert!(pushed > 1.0, "the oracle rendered a press: {pushed} N");
}

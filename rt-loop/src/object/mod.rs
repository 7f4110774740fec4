//! The simulated object the bench presses (issue 23: bench objects of any law). A material
//! file names its law (`law = "foam"` by default, [`material`]); each law is a module here
//! implementing [`Law`], and [`Object`] is the one the bench and the oracle step, whatever the
//! law:
//!
//! - [`foam`]: the viscoelastic foam of docs/physics.md, "The simulated sponge bench" (the default sponge, foam-b, foam-c);
//! - [`bouc_wen`]: a rate-independent hysteretic material (Bouc 1967, Wen 1976);
//! - [`poroelastic`]: a gel under a spherical indenter whose relaxation time grows with the
//!   contact size (Hu et al. 2010);
//! - [`onnx`]: any law exported as a stateful ONNX graph (docs/laws/onnx.md), stepped through
//!   ONNX Runtime at the rate its material file declares.
//!
//! [`oracle`] is the object's own physics as a force model (the rendering floor).
//!
//! An [`Object`] is an enum, not a `Box<dyn Law>`: the bench steps it tens of times per loop
//! period, so it is stepped by a `match` on inline state (no allocation, no indirection), and
//! a clone (the oracle's fresh copy for every run) copies plain values; an ONNX object's clone
//! shares the graph's session (`Arc`) and gets tensors of its own with the state copied.

pub mod bouc_wen;
pub mod foam;
pub mod material;
pub mod onnx;
pub mod onnx_graph;
pub mod oracle;
pub mod ort_runtime;
pub mod poroelastic;

use material::{LawParams, Material};

/// One law of a simulated object, stepped by the bench along the probe's position.
///
/// REAL-TIME PATH (the simulated bench's sub-steps, the oracle's predict): no method allocates,
/// takes a lock or makes a syscall.
pub trait Law {
    /// Prepares the sub-steps of `h` seconds that follow (cached factors).
    fn prepare(&mut self, h: f64);
    /// Advances to probe position `x` (m, positive into the object) over one prepared
    /// sub-step; returns the force (N, >= 0) with which the object pushes the probe back.
    fn substep(&mut self, x: f64) -> f64;
    /// The slow part, once per control period of `dt` seconds (a law without one ignores it).
    fn slow_update(&mut self, _x: f64, _dt: f64) {}
    /// The force of the last sub-step, N.
    fn force(&self) -> f64;
    /// Why the object can no longer be stepped (latched), if so: an ONNX object whose graph
    /// failed or answered a non-finite force. The simulated board stops the run with it.
    fn fault(&self) -> Option<&'static str> {
        None
    }
}

/// The simulated object of a material file, of whichever law it names.
// The foam's inline branch arrays make it the largest variant; boxing it would put an
// indirection in the bench's sub-step, and an Object is built once per run, not moved per step.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug)]
pub enum Object {
    Foam(foam::Sponge),
    BoucWen(bouc_wen::BoucWen),
    Poroelastic(poroelastic::Poroelastic),
    Onnx(onnx::OnnxObject),
}

impl Object {
    /// A fresh (unloaded) object of the material's law.
    pub fn new(m: &Material) -> Self {
        match &m.law {
            LawParams::Foam(f) => Object::Foam(foam::Sponge::new(f)),
            LawParams::BoucWen(b) => Object::BoucWen(bouc_wen::BoucWen::new(b)),
            LawParams::Poroelastic(p) => Object::Poroelastic(poroelastic::Poroelastic::new(p)),
            LawParams::Onnx(p) => Object::Onnx(onnx::OnnxObject::new(p)),
        }
    }

    /// The foam's state, when the object is a foam (its permanent set, largest depth).
    pub fn foam(&self) -> Option<&foam::Sponge> {
        match self {
            Object::Foam(s) => Some(s),
            _ => None,
        }
    }
}

impl Law for Object {
    #[inline]
    fn prepare(&mut self, h: f64) {
        match self {
            Object::Foam(o) => o.prepare(h),
            Object::BoucWen(o) => o.prepare(h),
            Object::Poroelastic(o) => o.prepare(h),
            Object::Onnx(o) => o.prepare(h),
        }
    }

    #[inline]
    fn substep(&mut self, x: f64) -> f64 {
        match self {
            Object::Foam(o) => o.substep(x),
            Object::BoucWen(o) => o.substep(x),
            Object::Poroelastic(o) => o.substep(x),
            Object::Onnx(o) => o.substep(x),
        }
    }

    #[inline]
    fn slow_update(&mut self, x: f64, dt: f64) {
        match self {
            Object::Foam(o) => o.slow_update(x, dt),
            Object::BoucWen(o) => o.slow_update(x, dt),
            Object::Poroelastic(o) => o.slow_update(x, dt),
            Object::Onnx(o) => o.slow_update(x, dt),
        }
    }

    #[inline]
    fn force(&self) -> f64 {
        match self {
            Object::Foam(o) => Law::force(o),
            Object::BoucWen(o) => o.force(),
            Object::Poroelastic(o) => o.force(),
            Object::Onnx(o) => o.force(),
        }
    }

    #[inline]
    fn fault(&self) -> Option<&'static str> {
        match self {
            Object::Onnx(o) => o.fault(),
            _ => None,
        }
    }
}

#[cfg(test)]
#[path = "../../../tests/src/skip.rs"]
mod skip;

#[cfg(test)]
mod tests {
    use super::*;

    /// Every material file of the repository parses, names a known law, and its object pushes
    /// back along a 15 mm press, only pushes, and gives 0 out of contact.
    #[test]
    fn every_repository_material_is_an_object_that_pushes() {
        let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/../materials");
        let mut laws = std::collections::BTreeSet::new();
        for entry in std::fs::read_dir(dir).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_none_or(|e| e != "toml") {
                continue;
            }
            let (m, _) = match Material::load(&path) {
                Ok(m) => m,
                // an `onnx` material needs ONNX Runtime: a counted skip, a failure under CI
                Err(e) if ort_runtime::environment().is_err() => {
                    skip::skip(&format!("{}: {e}", path.display()));
                    laws.insert("onnx");
                    continue;
                }
                Err(e) => panic!("{}: {e}", path.display()),
            };
            laws.insert(m.law.name());
            let mut o = Object::new(&m);
            o.prepare(1e-5);
            let mut peak: f64 = 0.0;
            for k in 0..=30_000 {
                let t = k as f64 * 1e-5; // 0.3 s: in to 15 mm and out again
                let x = 0.017 * (std::f64::consts::PI * t / 0.3).sin() - 0.002;
                let f = o.substep(x);
                o.slow_update(x, 1e-5);
                assert!(f >= 0.0 && f.is_finite(), "{}: {f} at {x}", path.display());
                if x <= 0.0 {
                    assert_eq!(f, 0.0, "{}: out of contact", path.display());
                }
                peak = peak.max(f);
            }
            assert!(
                peak > 1.0,
                "{}: a 15 mm press pushes back ({peak} N)",
                path.display()
            );
        }
        for law in material::LAWS {
            assert!(
                laws.contains(law),
                "no material file of law {law}: {laws:?}"
            );
        }
    }
}

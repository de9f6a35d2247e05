//! The double window's factors: Jacobians and retraction.

use super::*;
use geom::PinholeCamera;
use lsq::numeric::check_jacobians;
use nalgebra::Vector2;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn random_sim3(rng: &mut ChaCha8Rng, spread: f64) -> Sim3 {
    let mut t = SVector::<f64, 7>::from_fn(|_, _| rng.random_range(-spread..spread));
    t[6] *= 0.3;
    Sim3::exp(&t)
}

#[test]
fn window_factors_have_correct_jacobians() {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let cam = PinholeCamera::new(300.0, 310.0, 320.0, 240.0);
    for _ in 0..20 {
        let mut values = Values::new();
        let t_a = random_sim3(&mut rng, 0.1);
        let t_o = random_sim3(&mut rng, 0.1);
        let a = values.add(FixedScaleSim3(t_a));
        let o = values.add(FixedScaleSim3(t_o));
        let psi = values.add(Vector3::new(
            rng.random_range(-0.3..0.3),
            rng.random_range(-0.3..0.3),
            rng.random_range(0.2..0.6),
        ));
        let f = AnchoredObservation {
            observer_from_world: o,
            anchor_from_world: a,
            inverse_depth_point: psi,
            measurement: Vector2::new(300.0, 200.0),
            projector: cam,
        };
        let r = check_jacobians(&f, &values, 1e-6).expect("in front");
        assert!(r.passes(1e-5), "{r:?}");
        let b = WindowBetween {
            from: a,
            to: o,
            measured: random_sim3(&mut rng, 0.5),
        };
        let r = check_jacobians(&b, &values, 1e-6).unwrap();
        assert!(r.passes(1e-6), "{r:?}");
    }
}

#[test]
fn retraction_keeps_the_scale() {
    let mut t = FixedScaleSim3(Sim3::new(lie::So3::identity(), Vector3::zeros(), 1.7).unwrap());
    t.retract(&[0.1, 0.2, -0.3, 0.01, 0.02, 0.03]);
    assert!((t.0.scale() - 1.7).abs() < 1e-12);
}

//! Property tests of the conversions from the tick's volts to a board's command: for any `f64`
//! (NaN, infinities, subnormals, either zero, the extremes) as the value, the scale or the
//! board's range, they return a command inside the range and never panic (issue 26's audit found
//! `clamp` with a NaN range panicking inside the tick). Must never: skip a class of `f64`.

use proptest::prelude::*;

use crate::clamp_symmetric;
use crate::uart::protocol::volts_to_digits;
use crate::usb::protocol::volts_to_da;

/// One of each class of `f64`, both signs.
const SPECIAL: [f64; 16] = [
    f64::NAN,
    -f64::NAN,
    f64::INFINITY,
    f64::NEG_INFINITY,
    0.0,
    -0.0,
    f64::MIN_POSITIVE,
    -f64::MIN_POSITIVE,
    5e-324,
    -5e-324,
    f64::MAX,
    f64::MIN,
    1.0,
    -1.0,
    3.3,
    415.0,
];

/// What a range allows: nothing when it is NaN or negative.
fn allowed(max: f64) -> f64 {
    if max >= 0.0 {
        max
    } else {
        0.0
    }
}

fn check_digits(volts: f64, scale: f64, limit: i16) -> Result<(), TestCaseError> {
    let d = volts_to_digits(volts, scale, limit);
    prop_assert!(f64::from(d).abs() <= allowed(f64::from(limit)), "{volts} x {scale} within {limit}: {d}");
    if (volts * scale).is_nan() {
        prop_assert_eq!(d, 0);
    }
    Ok(())
}

fn check_da(volts: f64, scale: f64, volts_max: f64) -> Result<(), TestCaseError> {
    let d = volts_to_da(volts, scale, volts_max);
    prop_assert!(d != i16::MIN, "{volts} x {scale} within {volts_max}: {d}");
    if volts_max.is_nan() || volts_max < 0.0 || volts.is_nan() {
        prop_assert_eq!(d, 0, "{} x {} within {}", volts, scale, volts_max);
    }
    Ok(())
}

#[test]
fn every_class_of_f64_converts_inside_the_range_without_panicking() {
    let limits = [0, 1, 1024, 4095, i16::MAX, -1, -1024, i16::MIN];
    for v in SPECIAL {
        for k in SPECIAL {
            for l in limits {
                check_digits(v, k, l).unwrap();
            }
            for m in SPECIAL {
                check_da(v, k, m).unwrap();
                let c = clamp_symmetric(v, m);
                assert!(c.abs() <= allowed(m) && !c.is_nan(), "clamp_symmetric({v}, {m}) = {c}");
            }
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 20_000, ..ProptestConfig::default() })]

    #[test]
    fn volts_to_digits_never_panics_and_stays_in_range(
        v in proptest::num::f64::ANY,
        k in proptest::num::f64::ANY,
        l in any::<i16>(),
    ) {
        check_digits(v, k, l)?;
    }

    #[test]
    fn volts_to_da_never_panics_and_stays_in_range(
        v in proptest::num::f64::ANY,
        k in proptest::num::f64::ANY,
        m in proptest::num::f64::ANY,
    ) {
        check_da(v, k, m)?;
    }
}

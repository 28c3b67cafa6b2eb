//! The core is generic over the number of ADCs `N` and codes `CODES` at compile time;
//! files and camera configurations say them at run time. This is the one place that maps
//! one to the other.

/// Calls `$f::<N, CODES>(args...)` for the supported (ADCs, codes) pairs, or returns a
/// `HostError::UnsupportedDims` naming `$origin` (anything `Into<Origin>`: a path or a
/// `Subject`) for any other pair.
#[macro_export]
macro_rules! dispatch_lut_dims {
    ($n:expr, $codes:expr, $origin:expr, $f:ident ( $($arg:expr),* $(,)? )) => {
        match ($n, $codes) {
            (1, 256) => $f::<1, 256>($($arg),*),
            (1, 1024) => $f::<1, 1024>($($arg),*),
            (1, 4096) => $f::<1, 4096>($($arg),*),
            (1, 16384) => $f::<1, 16384>($($arg),*),
            (2, 256) => $f::<2, 256>($($arg),*),
            (2, 1024) => $f::<2, 1024>($($arg),*),
            (2, 4096) => $f::<2, 4096>($($arg),*),
            (2, 16384) => $f::<2, 16384>($($arg),*),
            (4, 256) => $f::<4, 256>($($arg),*),
            (4, 1024) => $f::<4, 1024>($($arg),*),
            (4, 4096) => $f::<4, 4096>($($arg),*),
            (4, 16384) => $f::<4, 16384>($($arg),*),
            (8, 256) => $f::<8, 256>($($arg),*),
            (8, 1024) => $f::<8, 1024>($($arg),*),
            (8, 4096) => $f::<8, 4096>($($arg),*),
            (n_adc, codes) => Err($crate::HostError::UnsupportedDims { origin: $crate::Origin::from($origin), n_adc, codes }),
        }
    };
}

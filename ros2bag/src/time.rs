//! `builtin_interfaces/msg/Time`.

use crate::error::{Error, Result};

/// A ROS 2 time stamp: whole seconds plus nanoseconds in `[0, 1e9)`.
///
/// Negative times are stored the ROS 2 way, with `sec` rounded down and a positive `nanosec`
/// (−0.25 s is `{sec: -1, nanosec: 750_000_000}`), so `sec + nanosec·1e-9` is always the time.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Time {
    pub sec: i32,
    pub nanosec: u32,
}

impl Time {
    const NANOS_PER_SEC: i64 = 1_000_000_000;

    /// The time `seconds` after the epoch, rounded to the nearest nanosecond.
    ///
    /// Fails for NaN, infinities, and times outside what i32 seconds can hold (before 1901 or
    /// after 2038), because `builtin_interfaces/Time` has no way to say them.
    pub fn from_seconds(seconds: f64) -> Result<Self> {
        let out_of_range = || Error::TimeOutOfRange { seconds };
        if !seconds.is_finite() {
            return Err(out_of_range());
        }
        let whole = seconds.floor();
        if !(whole >= f64::from(i32::MIN) && whole <= f64::from(i32::MAX)) {
            return Err(out_of_range());
        }
        let mut sec = whole as i64;
        let mut nanos = ((seconds - whole) * 1e9).round() as i64;
        if nanos >= Self::NANOS_PER_SEC {
            sec += 1;
            nanos -= Self::NANOS_PER_SEC;
        }
        let sec = i32::try_from(sec).map_err(|_| out_of_range())?;
        Ok(Self { sec, nanosec: nanos as u32 })
    }

    /// The time `nanos` nanoseconds after the epoch (the unit of bag log times).
    ///
    /// Fails after 2038, when the seconds no longer fit `i32`.
    pub fn from_nanos(nanos: u64) -> Result<Self> {
        let sec =
            i32::try_from(nanos / 1_000_000_000).map_err(|_| Error::TimeOutOfRange { seconds: nanos as f64 * 1e-9 })?;
        Ok(Self { sec, nanosec: (nanos % 1_000_000_000) as u32 })
    }

    /// Seconds since the epoch as a float (loses sub-microsecond precision for current dates).
    pub fn as_seconds(&self) -> f64 {
        f64::from(self.sec) + f64::from(self.nanosec) * 1e-9
    }

    /// Nanoseconds since the epoch; exact.
    pub fn as_nanos(&self) -> i64 {
        i64::from(self.sec) * Self::NANOS_PER_SEC + i64::from(self.nanosec)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn from_seconds_splits_and_rounds() {
        assert_eq!(Time::from_seconds(1.5).unwrap(), Time { sec: 1, nanosec: 500_000_000 });
        assert_eq!(Time::from_seconds(1.1).unwrap(), Time { sec: 1, nanosec: 100_000_000 });
        assert_eq!(Time::from_seconds(0.0).unwrap(), Time { sec: 0, nanosec: 0 });
        // 2 - 1e-10 rounds up to exactly 2 s, carrying into `sec`
        assert_eq!(Time::from_seconds(2.0 - 1e-10).unwrap(), Time { sec: 2, nanosec: 0 });
    }

    #[test]
    fn negative_times_keep_nanosec_positive() {
        assert_eq!(Time::from_seconds(-0.25).unwrap(), Time { sec: -1, nanosec: 750_000_000 });
        assert_eq!(Time::from_seconds(-0.25).unwrap().as_nanos(), -250_000_000);
    }

    #[test]
    fn unrepresentable_times_are_errors() {
        for s in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY, 3e9, -3e9] {
            assert!(matches!(Time::from_seconds(s), Err(Error::TimeOutOfRange { .. })), "{s}");
        }
        assert!(Time::from_nanos(u64::MAX).is_err());
    }

    #[test]
    fn from_nanos_is_exact() {
        let t = Time::from_nanos(1_700_000_000_123_456_789).unwrap();
        assert_eq!(t, Time { sec: 1_700_000_000, nanosec: 123_456_789 });
        assert_eq!(t.as_nanos(), 1_700_000_000_123_456_789);
    }
}

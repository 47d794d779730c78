//! How a measured signal answers a disturbance or a set-point step: the control engineer's
//! figures (peak, overshoot, settling time, steady-state error), from sampled time series.
//!
//! Definitions (docs/studies.md):
//! - **disturbance** (the set point stays, something knocks the signal off it at `onset`): the
//!   side it is knocked to is where it first leaves the band after the onset; the peak is the
//!   largest deviation on that side; the overshoot is the largest swing past the set point to
//!   the other side after the peak, as a fraction of the peak (a controller that catches a
//!   push too hard swings further back than the push moved it: over 100 %).
//! - **step** (the set point moves from the signal's value at `onset` to `target`): the
//!   overshoot is the largest excursion beyond the target, as a fraction of the step.
//! - Both: the settling time is the time from the onset until the signal enters the band
//!   around the set point for good — and stays in it for at least the last `window` seconds of
//!   the record (entering it just before the record ends is not settling); the steady-state error is |mean of y over the record's last
//!   `window` seconds − set point|.
//!
//! For a second-order system both overshoots are exp(−ζπ/√(1−ζ²)) (tested against it).

use serde::Serialize;

/// The figures of one response.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Response {
    /// Largest deviation from the set point on the side the signal was knocked to
    /// (disturbance) or from the start towards the target (step), signed, in the signal's units.
    pub peak: f64,
    /// When the peak came, after the onset (s).
    pub peak_time_s: f64,
    /// Fraction (0.25 = 25 %); 0 when the signal never crosses over.
    pub overshoot: f64,
    /// After the onset (s); `None` when the signal has not been inside the band for the
    /// record's last `window` seconds.
    pub settling_time_s: Option<f64>,
    /// |mean over the last window − set point|, in the signal's units.
    pub steady_state_error: f64,
    /// Largest |y − set point| after the onset, either side.
    pub max_deviation: f64,
}

/// A signal knocked off its `setpoint` at `onset` (s): settled once within ±`band` (absolute).
pub fn disturbance(t: &[f64], y: &[f64], onset: f64, setpoint: f64, band: f64, window: f64) -> Response {
    let start = first_at(t, onset);
    let deviation = |i: usize| y[i] - setpoint;
    let Some(largest) = (start..y.len()).max_by(|&a, &b| deviation(a).abs().total_cmp(&deviation(b).abs())) else {
        return empty(setpoint, y, t, window);
    };
    let side = (start..y.len()).map(deviation).find(|d| d.abs() > band).unwrap_or(deviation(largest)).signum();
    let peak_at =
        (start..y.len()).max_by(|&a, &b| (deviation(a) * side).total_cmp(&(deviation(b) * side))).unwrap_or(largest);
    let peak = deviation(peak_at);
    let swing = (peak_at..y.len()).map(|i| -deviation(i) * side).fold(0.0, f64::max);
    Response {
        peak,
        peak_time_s: t[peak_at] - onset,
        overshoot: if peak * side > 0.0 { swing / peak.abs() } else { 0.0 },
        settling_time_s: settling(t, y, start, onset, setpoint, band, window),
        steady_state_error: steady_state_error(t, y, setpoint, window),
        max_deviation: deviation(largest).abs(),
    }
}

/// A set-point step at `onset` from the signal's value then to `target`: settled once within
/// ±`band_fraction` of the step around the target (0.02: the 2 % settling time).
pub fn step(t: &[f64], y: &[f64], onset: f64, target: f64, band_fraction: f64, window: f64) -> Response {
    let start = first_at(t, onset);
    let Some(&initial) = y.get(start) else {
        return empty(target, y, t, window);
    };
    let size = target - initial;
    let direction = size.signum();
    let peak_at = (start..y.len())
        .max_by(|&a, &b| ((y[a] - initial) * direction).total_cmp(&((y[b] - initial) * direction)))
        .unwrap_or(start);
    let beyond = y[start..].iter().map(|v| (v - target) * direction).fold(0.0, f64::max);
    Response {
        peak: y[peak_at] - initial,
        peak_time_s: t[peak_at] - onset,
        overshoot: if size == 0.0 { 0.0 } else { beyond / size.abs() },
        settling_time_s: settling(t, y, start, onset, target, band_fraction * size.abs(), window),
        steady_state_error: steady_state_error(t, y, target, window),
        max_deviation: y[start..].iter().map(|v| (v - target).abs()).fold(0.0, f64::max),
    }
}

/// Index of the first sample at or after `time`.
fn first_at(t: &[f64], time: f64) -> usize {
    t.partition_point(|&s| s < time)
}

/// From the onset until the sample after the last one outside ±band around `target`, if that
/// is at least `window` before the record's end.
fn settling(t: &[f64], y: &[f64], start: usize, onset: f64, target: f64, band: f64, window: f64) -> Option<f64> {
    let end = *t.last()?;
    let entered = match (start..y.len()).rev().find(|&i| (y[i] - target).abs() > band) {
        None => t.get(start).copied().unwrap_or(end),
        Some(last) => *t.get(last + 1)?,
    };
    (end - entered >= window - 1e-9).then(|| (entered - onset).max(0.0))
}

fn steady_state_error(t: &[f64], y: &[f64], target: f64, window: f64) -> f64 {
    let Some(&end) = t.last() else { return 0.0 };
    let from = first_at(t, end - window);
    let tail = &y[from..];
    (tail.iter().sum::<f64>() / tail.len() as f64 - target).abs()
}

fn empty(target: f64, y: &[f64], t: &[f64], window: f64) -> Response {
    Response { steady_state_error: steady_state_error(t, y, target, window), ..Response::default() }
}

#[cfg(test)]
mod tests {
    use super::*;

    const DT: f64 = 1e-4;

    fn times(seconds: f64) -> Vec<f64> {
        (0..=(seconds / DT) as usize).map(|k| k as f64 * DT).collect()
    }

    /// The closed forms of x'' + 2ζω x' + ω² x = ω² u: its unit step and unit impulse responses.
    fn second_order(zeta: f64, omega: f64) -> (impl Fn(f64) -> f64, impl Fn(f64) -> f64, f64) {
        let damped = omega * (1.0 - zeta * zeta).sqrt();
        let step = move |t: f64| {
            1.0 - (-zeta * omega * t).exp()
                * ((damped * t).cos() + zeta / (1.0 - zeta * zeta).sqrt() * (damped * t).sin())
        };
        let impulse = move |t: f64| (-zeta * omega * t).exp() * (damped * t).sin() / damped;
        (step, impulse, damped)
    }

    fn overshoot_formula(zeta: f64) -> f64 {
        (-zeta * std::f64::consts::PI / (1.0 - zeta * zeta).sqrt()).exp()
    }

    #[test]
    fn step_response_of_a_second_order_system_matches_the_formulas() {
        for (zeta, omega) in [(0.3, 5.0), (0.6, 2.0), (0.1, 8.0)] {
            let (response, _, damped) = second_order(zeta, omega);
            let t = times(15.0);
            let y: Vec<f64> = t.iter().map(|&s| response(s)).collect();
            let r = step(&t, &y, 0.0, 1.0, 0.02, 1.0);
            assert!(
                (r.overshoot - overshoot_formula(zeta)).abs() < 1e-4,
                "ζ {zeta}: overshoot {} vs {}",
                r.overshoot,
                overshoot_formula(zeta)
            );
            assert!(
                (r.peak_time_s - std::f64::consts::PI / damped).abs() < 2.0 * DT,
                "ζ {zeta}: peak at {}",
                r.peak_time_s
            );
            // The envelope 1 + e^(−ζωt)/√(1−ζ²) enters the 2 % band at t_env; the response itself
            // enters it at most half a period earlier.
            let envelope = -(0.02 * (1.0 - zeta * zeta).sqrt()).ln() / (zeta * omega);
            let settled = r.settling_time_s.expect("settles within 15 s");
            assert!(
                settled <= envelope + DT && settled > envelope - std::f64::consts::PI / damped,
                "ζ {zeta}: settled {settled}, envelope {envelope}"
            );
            assert!(r.steady_state_error < 1e-3);
        }
    }

    #[test]
    fn a_knocked_second_order_system_swings_back_by_the_formula() {
        for (zeta, omega) in [(0.2, 4.0), (0.5, 3.0)] {
            let (_, impulse, damped) = second_order(zeta, omega);
            let onset = 2.0;
            let t = times(20.0);
            let y: Vec<f64> = t.iter().map(|&s| if s < onset { 0.0 } else { -0.3 * impulse(s - onset) }).collect();
            let band = 0.001;
            let r = disturbance(&t, &y, onset, 0.0, band, 1.0);
            assert!(
                (r.overshoot - overshoot_formula(zeta)).abs() < 1e-4,
                "ζ {zeta}: overshoot {} vs {}",
                r.overshoot,
                overshoot_formula(zeta)
            );
            let peak_time = ((1.0 - zeta * zeta).sqrt() / zeta).atan() / damped;
            assert!((r.peak_time_s - peak_time).abs() < 2.0 * DT, "ζ {zeta}: peak at {} vs {peak_time}", r.peak_time_s);
            assert!(r.peak < 0.0, "knocked downwards");
            let envelope = (0.3 / (damped * band)).ln() / (zeta * omega);
            let settled = r.settling_time_s.expect("settles");
            assert!(
                settled <= envelope + DT && settled > envelope - std::f64::consts::PI / damped,
                "ζ {zeta}: settled {settled}, envelope {envelope}"
            );
        }
    }

    #[test]
    fn a_swing_back_larger_than_the_push_is_an_overshoot_over_100_percent() {
        let t = times(6.0);
        // Knocked to +0.02 at 1 s, caught too hard: swings to −0.06, then decays.
        let y: Vec<f64> = t
            .iter()
            .map(|&s| match s {
                s if s < 1.0 => 0.0,
                s if s < 1.5 => 0.02 * ((s - 1.0) * std::f64::consts::PI / 0.5).sin(),
                s if s < 2.5 => -0.06 * ((s - 1.5) * std::f64::consts::PI).sin(),
                _ => 0.0,
            })
            .collect();
        let r = disturbance(&t, &y, 1.0, 0.0, 0.005, 1.0);
        assert!((r.peak - 0.02).abs() < 1e-6, "the push's own deflection: {}", r.peak);
        assert!((r.overshoot - 3.0).abs() < 1e-3, "{}", r.overshoot);
        assert!((r.max_deviation - 0.06).abs() < 1e-6);
        assert!((r.peak_time_s - 0.25).abs() < 2.0 * DT);
    }

    #[test]
    fn an_offset_is_the_steady_state_error_and_a_signal_outside_the_band_never_settles() {
        let t = times(10.0);
        let (response, _, _) = second_order(0.7, 3.0);
        let y: Vec<f64> = t.iter().map(|&s| 0.9 * response(s)).collect();
        let r = step(&t, &y, 0.0, 1.0, 0.02, 1.0);
        assert!((r.steady_state_error - 0.1).abs() < 1e-3, "{}", r.steady_state_error);
        assert_eq!(r.settling_time_s, None, "10 % off the target never enters the 2 % band");
        let drifting: Vec<f64> = t.iter().map(|&s| 0.1 * s).collect();
        assert_eq!(disturbance(&t, &drifting, 0.0, 0.0, 0.05, 1.0).settling_time_s, None);
    }
}

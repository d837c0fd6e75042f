//! How late the drawn picture is: the pages report, for every frame they draw, which world step
//! and rig tick it shows and its age (from the wall-clock time of the rig tick whose hand sample
//! it shows, carried in the frame's stamp, to the page's wall-clock time when it drew it), and
//! the view keeps the last [`WINDOW`] of each kind (a screen, a headset) for the status message
//! and for `spidar bench view`.
//!
//! Why the page measures: only the page knows when it drew. The two clocks are the same machine's
//! wall clock on localhost; a page on another machine (a headset) measures against its own, so its
//! figures are only as good as the two clocks agree (NTP: a few ms).
//!
//! Must never: run on the world's stepping thread (the viewers' threads write it, the broadcaster
//! reads it), or trust a report's numbers beyond a sanity bound.

use serde::Deserialize;

/// Reports kept per kind.
pub const WINDOW: usize = 1000;
/// Ages beyond this are not pictures of a live rig (a stalled page, a clock jump): dropped, counted.
const MAX_AGE_MS: f64 = 10_000.0;

/// One `drawn` report from a page (JSON text message `{"type":"drawn", ...}`).
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
pub struct Drawn {
    /// The frame's sequence number, world step and rig tick.
    pub seq: u32,
    pub step: u64,
    pub tick: u64,
    /// From the tick's wall-clock time to the page's, when the frame was drawn.
    pub age_ms: f64,
    /// How far behind that tick the drawn hands are (the age less how far the page extrapolated
    /// them; equal to the age when it does not).
    #[serde(default)]
    pub hand_lag_ms: Option<f64>,
    /// How long the page took to draw it (part of the age: a software renderer makes it long).
    #[serde(default)]
    pub draw_ms: f64,
    /// Drawn in an immersive (headset) session.
    #[serde(default)]
    pub xr: bool,
    /// Where the age went: from the tick to the frame's message arriving at the page (the world,
    /// the link, the broadcaster, the socket), and from its arrival to the start of its drawing
    /// (the wait for the browser's next frame). Pages that do not say: None.
    #[serde(default)]
    pub arrive_ms: Option<f64>,
    #[serde(default)]
    pub wait_ms: Option<f64>,
    /// How far (mm, the worse hand) an earlier picture drew the grips from where the rig measured
    /// them at the time it was shown (known once later frames cover that time), and how far the
    /// newest frame's grips, not extrapolated, were then. Pages that do not say: None.
    #[serde(default)]
    pub hand_err_mm: Option<f64>,
    #[serde(default)]
    pub hand_still_err_mm: Option<f64>,
}

impl Drawn {
    /// A report, if `text` is one (other texts are a replay's controls).
    pub fn parse(text: &str) -> Option<Drawn> {
        if !text.contains("\"drawn\"") {
            return None;
        }
        #[derive(Deserialize)]
        struct Typed {
            #[serde(rename = "type")]
            kind: String,
            #[serde(flatten)]
            drawn: Drawn,
        }
        let t: Typed = serde_json::from_str(text).ok()?;
        (t.kind == "drawn").then_some(t.drawn)
    }
}

/// Percentiles of one kind's window.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct AgeSummary {
    /// Reports in the window, and in all.
    pub frames: usize,
    pub total: u64,
    pub p50_ms: f64,
    pub p99_ms: f64,
    pub max_ms: f64,
    pub hand_lag_p50_ms: f64,
    pub hand_lag_p99_ms: f64,
    pub draw_p50_ms: f64,
    pub draw_p99_ms: f64,
    /// The tick to the message's arrival, and the arrival to the drawing (NaN: not reported).
    pub arrive_p50_ms: f64,
    pub arrive_p99_ms: f64,
    pub wait_p50_ms: f64,
    pub wait_p99_ms: f64,
    /// The grips' distance from the measured hands when shown, drawn as drawn (extrapolated) and
    /// as the newest frame had them (mm; NaN: not reported).
    pub hand_err_p50_mm: f64,
    pub hand_err_p99_mm: f64,
    pub hand_err_max_mm: f64,
    pub hand_still_err_p50_mm: f64,
    pub hand_still_err_p99_mm: f64,
    pub hand_still_err_max_mm: f64,
    /// The newest report's step and tick.
    pub step: u64,
    pub tick: u64,
}

#[derive(Clone, Debug, Default)]
struct Window {
    ages_ms: Vec<f64>,
    lags_ms: Vec<f64>,
    draws_ms: Vec<f64>,
    arrives_ms: Vec<f64>,
    waits_ms: Vec<f64>,
    errs_mm: Vec<f64>,
    still_errs_mm: Vec<f64>,
    next: usize,
    total: u64,
    step: u64,
    tick: u64,
}

impl Window {
    fn push(&mut self, d: &Drawn) {
        let lag = d.hand_lag_ms.unwrap_or(d.age_ms);
        if self.ages_ms.len() < WINDOW {
            self.ages_ms.push(d.age_ms);
            self.lags_ms.push(lag);
            self.draws_ms.push(d.draw_ms);
            self.arrives_ms.push(d.arrive_ms.unwrap_or(f64::NAN));
            self.waits_ms.push(d.wait_ms.unwrap_or(f64::NAN));
            self.errs_mm.push(d.hand_err_mm.unwrap_or(f64::NAN));
            self.still_errs_mm.push(d.hand_still_err_mm.unwrap_or(f64::NAN));
        } else {
            self.ages_ms[self.next] = d.age_ms;
            self.lags_ms[self.next] = lag;
            self.draws_ms[self.next] = d.draw_ms;
            self.arrives_ms[self.next] = d.arrive_ms.unwrap_or(f64::NAN);
            self.waits_ms[self.next] = d.wait_ms.unwrap_or(f64::NAN);
            self.errs_mm[self.next] = d.hand_err_mm.unwrap_or(f64::NAN);
            self.still_errs_mm[self.next] = d.hand_still_err_mm.unwrap_or(f64::NAN);
        }
        self.next = (self.next + 1) % WINDOW;
        self.total += 1;
        self.step = d.step;
        self.tick = d.tick;
    }

    fn summary(&self) -> Option<AgeSummary> {
        if self.ages_ms.is_empty() {
            return None;
        }
        let pct = |v: &[f64], p: f64| {
            let mut s = v.to_vec();
            s.sort_by(f64::total_cmp);
            s[((s.len() - 1) as f64 * p).round() as usize]
        };
        // Percentiles of the reports that carried the figure (NaN: none did).
        let known = |v: &[f64], p: f64| {
            let k: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
            if k.is_empty() {
                f64::NAN
            } else {
                pct(&k, p)
            }
        };
        Some(AgeSummary {
            frames: self.ages_ms.len(),
            total: self.total,
            p50_ms: pct(&self.ages_ms, 0.5),
            p99_ms: pct(&self.ages_ms, 0.99),
            max_ms: pct(&self.ages_ms, 1.0),
            hand_lag_p50_ms: pct(&self.lags_ms, 0.5),
            hand_lag_p99_ms: pct(&self.lags_ms, 0.99),
            draw_p50_ms: pct(&self.draws_ms, 0.5),
            draw_p99_ms: pct(&self.draws_ms, 0.99),
            arrive_p50_ms: known(&self.arrives_ms, 0.5),
            arrive_p99_ms: known(&self.arrives_ms, 0.99),
            wait_p50_ms: known(&self.waits_ms, 0.5),
            wait_p99_ms: known(&self.waits_ms, 0.99),
            hand_err_p50_mm: known(&self.errs_mm, 0.5),
            hand_err_p99_mm: known(&self.errs_mm, 0.99),
            hand_err_max_mm: known(&self.errs_mm, 1.0),
            hand_still_err_p50_mm: known(&self.still_errs_mm, 0.5),
            hand_still_err_p99_mm: known(&self.still_errs_mm, 0.99),
            hand_still_err_max_mm: known(&self.still_errs_mm, 1.0),
            step: self.step,
            tick: self.tick,
        })
    }
}

/// The pictures' ages the pages reported: a screen's and a headset's.
#[derive(Clone, Debug, Default)]
pub struct PictureAges {
    screen: Window,
    headset: Window,
    /// Reports refused: not finite, negative beyond clock noise, or beyond [`MAX_AGE_MS`].
    pub refused: u64,
}

impl PictureAges {
    pub fn record(&mut self, d: &Drawn) {
        // A page's clock may run a little behind the world's (another machine): allow 50 ms.
        let sane = |v: f64| v.is_finite() && (-50.0..=MAX_AGE_MS).contains(&v);
        if !(sane(d.age_ms) && d.hand_lag_ms.is_none_or(sane) && d.draw_ms.is_finite() && d.draw_ms >= 0.0) {
            self.refused += 1;
            return;
        }
        if d.xr {
            self.headset.push(d)
        } else {
            self.screen.push(d)
        }
    }

    /// The screen pages' and the headset pages' windows (None: no report of that kind).
    pub fn summaries(&self) -> (Option<AgeSummary>, Option<AgeSummary>) {
        (self.screen.summary(), self.headset.summary())
    }

    /// Forgets every report (a benchmark's next block).
    pub fn clear(&mut self) {
        *self = PictureAges::default();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_drawn_report_parses_and_other_texts_do_not() {
        let d = Drawn::parse(r#"{"type":"drawn","seq":3,"step":120,"tick":360,"age_ms":12.5,"xr":true}"#)
            .unwrap();
        assert_eq!((d.seq, d.step, d.tick, d.age_ms, d.hand_lag_ms, d.xr), (3, 120, 360, 12.5, None, true));
        assert!(Drawn::parse(r#"{"cmd":"play"}"#).is_none());
        assert!(Drawn::parse(r#"{"type":"drawn","seq":"x"}"#).is_none());
    }

    #[test]
    fn the_window_keeps_the_newest_reports_per_kind_and_refuses_nonsense() {
        let mut a = PictureAges::default();
        let d = |age: f64, xr: bool| Drawn {
            seq: 0,
            step: 1,
            tick: 2,
            age_ms: age,
            hand_lag_ms: None,
            draw_ms: 1.0,
            xr,
            arrive_ms: None,
            wait_ms: None,
            hand_err_mm: None,
            hand_still_err_mm: None,
        };
        // 1..=100 ms on the screen, then WINDOW more of 1000 ms push the first ones out.
        for k in 1..=100 {
            a.record(&d(k as f64, false));
        }
        let (s, h) = a.summaries();
        let s = s.unwrap();
        assert!(h.is_none());
        assert_eq!((s.frames, s.p50_ms, s.p99_ms, s.max_ms), (100, 51.0, 99.0, 100.0));
        for _ in 0..WINDOW {
            a.record(&d(1000.0, false));
        }
        let s = a.summaries().0.unwrap();
        assert_eq!((s.frames, s.total, s.p50_ms), (WINDOW, 100 + WINDOW as u64, 1000.0));
        a.record(&d(f64::NAN, true));
        a.record(&d(-500.0, true));
        a.record(&d(1e9, true));
        assert_eq!(a.refused, 3);
        assert!(a.summaries().1.is_none());
        a.record(&Drawn { hand_lag_ms: Some(4.0), ..d(20.0, true) });
        let h = a.summaries().1.unwrap();
        assert_eq!((h.p50_ms, h.hand_lag_p50_ms), (20.0, 4.0));
        // Where the age went: only from the reports that say (an older page's do not).
        assert!(h.arrive_p50_ms.is_nan() && h.wait_p99_ms.is_nan());
        a.record(&Drawn { arrive_ms: Some(3.0), wait_ms: Some(9.0), ..d(20.0, true) });
        let h = a.summaries().1.unwrap();
        assert_eq!((h.arrive_p50_ms, h.wait_p99_ms), (3.0, 9.0));
        assert!(h.hand_err_p50_mm.is_nan(), "no page said how far its grips were");
        a.record(&Drawn { hand_err_mm: Some(2.0), hand_still_err_mm: Some(30.0), ..d(20.0, true) });
        let h = a.summaries().1.unwrap();
        assert_eq!((h.hand_err_p99_mm, h.hand_err_max_mm, h.hand_still_err_p50_mm), (2.0, 2.0, 30.0));
    }
}

//! The `boards:` section of a rig file: per kind of board, what a string's command is and its
//! real range, and how the strings' volts (`volts_per_newton`) become the board's digits.
//!
//! Why it exists: the rt-loop computes one number per string, "volts" (tension x volts per
//! newton), but the boards do different things with it. On the USB boards it is a DA voltage
//! into a current amplifier. On UART boards without current sensors (B1M, B2M, B1F, B2F, B5M) the
//! command is a PWM duty (1024 = 100 %, clipped there); on B3M/B3F a current target (up to 4095
//! current-sense counts). Each has its own range, which the safety bounds use, and each rig its
//! own scale. Nothing here runs in the tick.

use serde::{Deserialize, Serialize};

use crate::config::{At, Checker, ConfigError};
use spidar_device::uart::protocol::{CURRENT_MAX, HOST_DIGITS_PER_VOLT, MAGNET_COUNTS_PER_REV, PWM_FULL};
use spidar_device::usb::protocol::DEFAULT_DIGITS_PER_VOLT as USB_DIGITS_PER_VOLT;

/// The `boards:` section (optional; every part has a default).
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct BoardsFile {
    /// USB Simple / SH-4: the command is a DA voltage.
    #[serde(default)]
    pub usb_da: UsbDaFile,
    /// UART boards without current sensors: the command is a PWM duty (default: full duty at
    /// 0.825 V, the lab host driver's scale).
    #[serde(default = "FullScaleFile::lab_pwm")]
    pub uart_pwm_duty: FullScaleFile,
    /// UART boards with current sensors: the command is a current target (default: 4095 at
    /// 3.3 V, the lab host driver's scale).
    #[serde(default = "FullScaleFile::lab_current")]
    pub uart_current_target: FullScaleFile,
    /// What the UART boards' position counts are.
    #[serde(default)]
    pub uart_counts: UartCounts,
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct UsbDaFile {
    /// DA digits per volt (415 measured on the lab's amplifiers; measure yours).
    #[serde(default = "UsbDaFile::lab_digits_per_volt")]
    pub digits_per_volt: f64,
    /// The DA output is clamped to +-this. Optional: what the rig needs (the largest
    /// tension_max_n x |volts_per_newton| of its strings).
    #[serde(default, deserialize_with = "plain_some", skip_serializing_if = "Option::is_none")]
    pub limit_v: Option<f64>,
}

impl UsbDaFile {
    fn lab_digits_per_volt() -> f64 {
        USB_DIGITS_PER_VOLT
    }
}

impl Default for UsbDaFile {
    fn default() -> Self {
        UsbDaFile { digits_per_volt: USB_DIGITS_PER_VOLT, limit_v: None }
    }
}

/// An optional number written plainly (`limit_v: 4.0`, not `Some(4.0)`).
fn plain_some<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Option<f64>, D::Error> {
    f64::deserialize(d).map(Some)
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct FullScaleFile {
    /// The strings' volts at which the command reaches its full scale (100 % duty, or a current
    /// target of 4095); beyond it the command clips.
    pub full_scale_v: f64,
}

impl FullScaleFile {
    fn lab_pwm() -> FullScaleFile {
        FullScaleFile { full_scale_v: f64::from(PWM_FULL) / HOST_DIGITS_PER_VOLT }
    }
    fn lab_current() -> FullScaleFile {
        FullScaleFile { full_scale_v: f64::from(CURRENT_MAX) / HOST_DIGITS_PER_VOLT }
    }
}

impl Default for BoardsFile {
    fn default() -> Self {
        BoardsFile {
            usb_da: UsbDaFile::default(),
            uart_pwm_duty: FullScaleFile::lab_pwm(),
            uart_current_target: FullScaleFile::lab_current(),
            uart_counts: UartCounts::MagnetAngle,
        }
    }
}

/// What a UART board's position counts are.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
pub enum UartCounts {
    /// The motor's magnetic angle sensor: 1024 counts per revolution (the boards' default).
    #[default]
    MagnetAngle,
    /// Raw quadrature counts (set in the board's non-volatile memory).
    Encoder { counts_per_rev: u32 },
}

/// The validated section.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BoardScales {
    pub usb_digits_per_volt: f64,
    /// USB DA clamp, volts.
    pub usb_limit_v: f64,
    /// UART PWM-duty digits per volt (1024 / full scale).
    pub uart_pwm_digits_per_volt: f64,
    /// UART current-target digits per volt (4095 / full scale).
    pub uart_current_digits_per_volt: f64,
    pub uart_counts: UartCounts,
}

impl BoardScales {
    /// Position counts per motor revolution on the UART boards.
    pub fn uart_counts_per_rev(&self) -> u32 {
        match self.uart_counts {
            UartCounts::MagnetAngle => MAGNET_COUNTS_PER_REV,
            UartCounts::Encoder { counts_per_rev } => counts_per_rev,
        }
    }
    /// The volts at which the UART PWM duty reaches 100 %.
    pub fn uart_pwm_full_scale_v(&self) -> f64 {
        f64::from(PWM_FULL) / self.uart_pwm_digits_per_volt
    }
    /// The volts at which the UART current target reaches 4095.
    pub fn uart_current_full_scale_v(&self) -> f64 {
        f64::from(CURRENT_MAX) / self.uart_current_digits_per_volt
    }
}

/// Checks the section for a rig whose strings need `volts_needed_v` at their highest tension
/// (`rig::volts_needed`: the DA limit when the file leaves it out), every error located by `c`.
pub fn validate(f: &BoardsFile, volts_needed_v: f64, c: &Checker) -> Result<BoardScales, ConfigError> {
    let at = |field: String, key: &'static str| At::new(field, key, 0);
    let positive = |v: f64, hi: f64| v.is_finite() && v > 0.0 && v <= hi;
    let usb = &f.usb_da;
    let per_volt = usb.digits_per_volt;
    c.ensure(
        positive(per_volt, f64::from(i16::MAX)),
        &at("boards.usb_da.digits_per_volt".into(), "digits_per_volt"),
        || format!("{per_volt}: must be > 0 and at most {} (the DA's 16 bits)", i16::MAX),
    )?;
    let limit = usb.limit_v.unwrap_or(volts_needed_v);
    let da_max = f64::from(i16::MAX) / per_volt;
    c.ensure(positive(limit, da_max), &at("boards.usb_da.limit_v".into(), "limit_v"), || {
        format!("{limit} V: must be > 0 and at most {da_max:.2} V (the DA's 16 bits at this scale)")
    })?;
    let full = |part: &FullScaleFile, digits: f64, name: &str| {
        let v = part.full_scale_v;
        let at = at(format!("boards.{name}.full_scale_v"), "full_scale_v");
        c.ensure(positive(v, 1000.0), &at, || format!("{v} V: must be > 0 and at most 1000 V"))?;
        Ok::<f64, ConfigError>(digits / v)
    };
    let pwm = full(&f.uart_pwm_duty, f64::from(PWM_FULL), "uart_pwm_duty")?;
    let current = full(&f.uart_current_target, f64::from(CURRENT_MAX), "uart_current_target")?;
    let counts = f.uart_counts;
    let encoder_without_counts = matches!(counts, UartCounts::Encoder { counts_per_rev: 0 });
    c.ensure(!encoder_without_counts, &at("boards.uart_counts".into(), "counts_per_rev"), || {
        "0: must be > 0".into()
    })?;
    Ok(BoardScales {
        usb_digits_per_volt: per_volt,
        usb_limit_v: limit,
        uart_pwm_digits_per_volt: pwm,
        uart_current_digits_per_volt: current,
        uart_counts: counts,
    })
}

//! The 16-bit DAC of the current amplifier: 0-5 V, 2.5 V (word 32768) = 0 A, full scale
//! +-`full_scale` A. The loop sends the word; the amplifier produces the quantised current.

/// Word for a current: rounds to the nearest code and saturates at the ends of the range.
#[inline]
pub fn current_to_word(current: f64, full_scale: f64) -> u16 {
    if current.is_nan() {
        return 32768; // never command an undefined current: zero
    }
    let code = 32768.0 + (current / full_scale * 32768.0).round();
    code.clamp(0.0, 65535.0) as u16
}

/// The current the amplifier makes from a word.
#[inline]
pub fn word_to_current(word: u16, full_scale: f64) -> f64 {
    (word as f64 - 32768.0) / 32768.0 * full_scale
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn zero_mid_scale_and_saturation() {
        assert_eq!(current_to_word(0.0, 0.6), 32768);
        assert_eq!(current_to_word(f64::NAN, 0.6), 32768);
        assert_eq!(current_to_word(10.0, 0.6), 65535);
        assert_eq!(current_to_word(-10.0, 0.6), 0);
        let lsb = 0.6 / 32768.0;
        for i in [-0.59, -0.1234, 0.0001, 0.3, 0.59] {
            let back = word_to_current(current_to_word(i, 0.6), 0.6);
            assert!((back - i).abs() <= lsb / 2.0 + 1e-15, "{i} -> {back}");
        }
    }
}

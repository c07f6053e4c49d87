//! The `$GPRMC` sentence of a position packet: the UTC date and time a GPS gives the sensor.
//! Reading it recovers the hour the data packets' µs counter is relative to; writing it lets the
//! simulator and tests produce GPS-locked captures.

/// Nanoseconds per second.
pub const NS_PER_S: u64 = 1_000_000_000;

/// Days since 1970-01-01 of a proleptic Gregorian date (Hinnant's `days_from_civil`).
pub fn days_from_civil(year: i64, month: u32, day: u32) -> i64 {
    let y = if month <= 2 { year - 1 } else { year };
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let m = month as i64;
    let doy = (153 * (if m > 2 { m - 3 } else { m + 9 }) + 2) / 5 + day as i64 - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    era * 146_097 + doe - 719_468
}

/// The date of a day count since 1970-01-01 (Hinnant's `civil_from_days`).
pub fn civil_from_days(days: i64) -> (i64, u32, u32) {
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let month = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    let year = yoe + era * 400 + i64::from(month <= 2);
    (year, month, day)
}

/// A parsed `$GPRMC` fix.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RmcFix {
    /// UTC time of the fix, ns since the Unix epoch.
    pub unix_ns: u64,
    /// Status `A` (valid) rather than `V`.
    pub valid: bool,
}

/// Parses a `$GPRMC` (or `$GNRMC`) sentence. Returns `None` for anything else, for an empty
/// or all-zero sentence, or for a date or time that does not parse. The checksum, when present,
/// must match.
pub fn parse_rmc(sentence: &[u8]) -> Option<RmcFix> {
    let text = std::str::from_utf8(sentence).ok()?.trim();
    let body = text.strip_prefix('$')?;
    let (body, checksum) = match body.split_once('*') {
        Some((b, c)) => (b, Some(c)),
        None => (body, None),
    };
    if let Some(c) = checksum {
        let expected = u8::from_str_radix(c.get(..2)?, 16).ok()?;
        if body.bytes().fold(0u8, |acc, b| acc ^ b) != expected {
            return None;
        }
    }
    let mut fields = body.split(',');
    let talker = fields.next()?;
    if !(talker.len() == 5 && &talker[2..] == "RMC") {
        return None;
    }
    let time = fields.next()?;
    let status = fields.next()?;
    // lat, N/S, lon, E/W, speed, course, then the date.
    let date = fields.nth(6)?;
    if time.len() < 6 || date.len() != 6 {
        return None;
    }
    let num = |s: &str| s.parse::<u32>().ok();
    let (hh, mm) = (num(&time[0..2])?, num(&time[2..4])?);
    let secs: f64 = time[4..].parse().ok()?;
    let (day, month, yy) = (num(&date[0..2])?, num(&date[2..4])?, num(&date[4..6])?);
    if hh > 23 || mm > 59 || !(0.0..61.0).contains(&secs) || !(1..=12).contains(&month) {
        return None;
    }
    if !(1..=31).contains(&day) {
        return None;
    }
    // Two-digit years: 80–99 are 1980s–1990s (GPS began in 1980), the rest 2000s.
    let year = if yy >= 80 { 1900 + yy } else { 2000 + yy } as i64;
    let days = days_from_civil(year, month, day);
    if days < 0 {
        return None;
    }
    let whole = days as u64 * 86_400 + u64::from(hh) * 3600 + u64::from(mm) * 60;
    let unix_ns = whole * NS_PER_S + (secs * 1e9).round() as u64;
    Some(RmcFix {
        unix_ns,
        valid: status == "A",
    })
}

/// Writes a valid `$GPRMC` sentence (with checksum and `\r\n`) for a Unix time, at a fixed
/// position. Seconds are written whole, as a 1 Hz receiver reports the PPS edge.
pub fn format_rmc(unix_ns: u64) -> String {
    let secs = unix_ns / NS_PER_S;
    let (year, month, day) = civil_from_days((secs / 86_400) as i64);
    let tod = secs % 86_400;
    let body = format!(
        "GPRMC,{:02}{:02}{:02},A,4916.45,N,12311.12,W,000.0,000.0,{:02}{:02}{:02},000.0,E",
        tod / 3600,
        (tod / 60) % 60,
        tod % 60,
        day,
        month,
        year.rem_euclid(100)
    );
    let checksum = body.bytes().fold(0u8, |acc, b| acc ^ b);
    format!("${body}*{checksum:02X}\r\n")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn civil_days_known_dates() {
        assert_eq!(days_from_civil(1970, 1, 1), 0);
        assert_eq!(days_from_civil(2000, 3, 1), 11_017);
        assert_eq!(days_from_civil(2026, 11, 23), 20_780);
        for d in [-1000, 0, 59, 365, 11_016, 20_780, 40_000] {
            let (y, m, dd) = civil_from_days(d);
            assert_eq!(days_from_civil(y, m, dd), d);
        }
    }

    #[test]
    fn parses_a_real_style_sentence() {
        // A textbook example sentence (checksum 6A is the sentence's own).
        let s = b"$GPRMC,123519,A,4807.038,N,01131.000,E,022.4,084.4,230394,003.1,W*6A";
        let fix = parse_rmc(s).unwrap();
        assert!(fix.valid);
        // 1994-03-23 12:35:19 UTC
        assert_eq!(fix.unix_ns, 764_426_119 * NS_PER_S);
    }

    #[test]
    fn round_trip_and_rejections() {
        let t = 1_795_000_000 * NS_PER_S;
        let s = format_rmc(t);
        assert_eq!(parse_rmc(s.as_bytes()).unwrap().unix_ns, t);
        let mut bad = s.clone().into_bytes();
        bad[10] = b'9';
        assert!(parse_rmc(&bad).is_none(), "checksum must catch corruption");
        assert!(parse_rmc(b"").is_none());
        assert!(parse_rmc(b"$GPGGA,1,2,3").is_none());
        assert!(parse_rmc(b"$GPRMC,000000,V,0,N,0,E,0,0,000000,,*00").is_none());
    }
}

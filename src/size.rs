//! Sizes in bytes as users write them (`--memory 4GiB`, `--cache 512MiB`).

/// A size in bytes as users write it: a whole or decimal number and a binary unit, `B`, `KiB`,
/// `MiB`, `GiB` or `TiB` (`4GiB`, `1.5GiB`, `512 MiB`). Decimal units (`GB`, `MB`) are refused
/// with the binary spelling, so that `4GB` is not taken as 4 GiB or 4 * 10^9 by guess.
pub fn parse_size(text: &str) -> std::result::Result<u64, String> {
    let t = text.trim();
    let units = [
        ("TiB", 1u64 << 40),
        ("GiB", 1 << 30),
        ("MiB", 1 << 20),
        ("KiB", 1 << 10),
        ("B", 1),
    ];
    let expected = "a size with a binary unit: B, KiB, MiB, GiB or TiB (4GiB, 512MiB)";
    for (unit, mult) in units {
        if let Some(n) = t.strip_suffix(unit) {
            let n = n.trim();
            if let Some((_, decimal)) = [
                ("T", "TiB"),
                ("G", "GiB"),
                ("M", "MiB"),
                ("K", "KiB"),
                ("k", "KiB"),
            ]
            .iter()
            .find(|(d, _)| unit == "B" && n.ends_with(d))
            {
                let number = &n[..n.len() - 1];
                return Err(format!(
                    "'{t}': decimal units are not taken; for binary units write {number}{decimal} (1 {decimal} = {} bytes)",
                    units.iter().find(|u| u.0 == *decimal).map_or(0, |u| u.1)
                ));
            }
            let value: f64 = n
                .parse()
                .ok()
                .filter(|v: &f64| v.is_finite() && *v >= 0.0)
                .ok_or_else(|| format!("'{t}': expected {expected}"))?;
            let bytes = value * mult as f64;
            if bytes >= u64::MAX as f64 {
                return Err(format!("'{t}': too large"));
            }
            return Ok(bytes.round() as u64);
        }
    }
    Err(format!("'{t}': expected {expected}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_take_binary_units() {
        assert_eq!(parse_size("4GiB"), Ok(4 << 30));
        assert_eq!(parse_size(" 512 MiB "), Ok(512 << 20));
        assert_eq!(parse_size("1.5GiB"), Ok(3 << 29));
        assert_eq!(parse_size("64KiB"), Ok(64 << 10));
        assert_eq!(parse_size("2TiB"), Ok(2 << 40));
        assert_eq!(parse_size("100B"), Ok(100));
        let e = parse_size("4GB").unwrap_err();
        assert!(e.contains("decimal units") && e.contains("4GiB"), "{e}");
        assert!(parse_size("4MB").unwrap_err().contains("4MiB"));
        for bad in [
            "abc", "", "GiB", "-1GiB", "4", "4 gigs", "nanGiB", "1e30TiB",
        ] {
            assert!(parse_size(bad).is_err(), "{bad}");
        }
    }
}

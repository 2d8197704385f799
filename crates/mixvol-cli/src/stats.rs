//! Minimum, median, 95th percentile and maximum of a timing series: the one summary every
//! command prints; and the process's peak RSS.

/// min / median / max of a series of times.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Summary {
    /// The smallest value.
    pub min: f64,
    /// The middle value (the upper one of the two middles for an even count).
    pub median: f64,
    /// The 95th percentile (nearest rank: the value at rank `ceil(0.95 n)`).
    pub p95: f64,
    /// The largest value.
    pub max: f64,
}

impl Summary {
    /// The summary of `values`; `None` when there are none.
    pub fn of(values: &[f64]) -> Option<Self> {
        if values.is_empty() {
            return None;
        }
        let mut v = values.to_vec();
        v.sort_by(|a, b| a.total_cmp(b));
        Some(Self {
            min: v[0],
            median: v[v.len() / 2],
            p95: v[(v.len() * 95).div_ceil(100).max(1) - 1],
            max: v[v.len() - 1],
        })
    }
}

/// The process's peak resident set (`VmHWM` of /proc/self/status), in bytes.
pub fn peak_rss_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

#[cfg(test)]
mod tests {
    use super::Summary;

    #[test]
    fn summary_orders_and_picks_the_middle() {
        let s = Summary::of(&[3.0, 1.0, 2.0, 9.0]).unwrap();
        assert_eq!((s.min, s.median, s.max), (1.0, 3.0, 9.0));
        assert_eq!(s.p95, 9.0);
        let ranks: Vec<f64> = (1..=40).map(f64::from).collect();
        assert_eq!(Summary::of(&ranks).unwrap().p95, 38.0);
        assert_eq!(Summary::of(&[]), None);
    }
}

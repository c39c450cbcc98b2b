//! Image sequences the oiiotool way: `render.####.exr` (one digit per `#`; a lone `#` is
//! four digits), `render.@@@.exr` (one digit per `@`), `render.%04d.exr`; frame lists
//! `1-100`, `1-100x5`, `1,3,5`, combined with commas.

use std::path::{Path, PathBuf};

/// A file-name pattern with one frame-number field.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Pattern {
    prefix: String,
    suffix: String,
    /// Zero-padding width.
    pub width: usize,
}

impl Pattern {
    /// Finds the frame field in `s`; `None` when `s` names a single file.
    pub fn parse(s: &str) -> Option<Pattern> {
        if let Some(start) = s.find("%0").or_else(|| s.find("%d")) {
            let rest = &s[start + 1..];
            let end = rest.find('d')?;
            let width = if end == 0 { 1 } else { rest[..end].parse().ok()? };
            return Some(Pattern { prefix: s[..start].into(), suffix: rest[end + 1..].into(), width });
        }
        for c in ['#', '@'] {
            if let Some(start) = s.find(c) {
                let n = s[start..].chars().take_while(|&x| x == c).count();
                let width = if c == '#' && n == 1 { 4 } else { n };
                return Some(Pattern { prefix: s[..start].into(), suffix: s[start + n..].into(), width });
            }
        }
        None
    }

    /// The path of frame `f`. The width counts a negative frame's sign, as printf's `%04d`
    /// (and so oiiotool, Blender and Houdini) writes it: frame −1 of `####` is `-001`.
    pub fn path(&self, f: i64) -> PathBuf {
        PathBuf::from(format!("{}{f:0w$}{}", self.prefix, self.suffix, w = self.width))
    }

    /// Frames whose files exist, found by listing the folder.
    pub fn existing_frames(&self) -> Vec<i64> {
        let p = Path::new(&self.prefix);
        let (dir, stem) = if self.prefix.ends_with('/') {
            (p.to_path_buf(), String::new())
        } else {
            let dir = p.parent().map(Path::to_path_buf).unwrap_or_default();
            (dir, p.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default())
        };
        let listing = std::fs::read_dir(if dir.as_os_str().is_empty() { Path::new(".") } else { &dir });
        let mut frames: Vec<i64> = listing
            .into_iter()
            .flatten()
            .flatten()
            .filter_map(|e| {
                let name = e.file_name().to_string_lossy().into_owned();
                let digits = name.strip_prefix(&stem)?.strip_suffix(&self.suffix)?.to_string();
                let ok = !digits.is_empty() && digits.trim_start_matches('-').chars().all(|c| c.is_ascii_digit());
                let f: i64 = if ok { digits.parse().ok()? } else { return None };
                // Only names this pattern writes: `@@@` does not match render.0001.exr, whose
                // frame it would name render.001.exr.
                (self.path(f).file_name()? == e.file_name()).then_some(f)
            })
            .collect();
        frames.sort_unstable();
        frames.dedup();
        frames
    }
}

/// The most frames one run takes: a typo like `1-100000000` is refused at once instead of
/// listing 10⁸ frames.
pub const MAX_FRAMES: u64 = 1_000_000;

/// Frames missing inside `frames`' range (sorted input), as `3, 7-9` spans.
pub fn gaps(frames: &[i64]) -> Vec<(i64, i64)> {
    frames.windows(2).filter(|w| w[1] > w[0] + 1).map(|w| (w[0] + 1, w[1] - 1)).collect()
}

/// Parses `1-100`, `1-100x5`, `1,3,5` and comma-separated combinations.
pub fn parse_frames(spec: &str) -> Result<Vec<i64>, String> {
    let bad = || format!("`{spec}` is not a frame list — use e.g. 1-100, 1-100x5 or 1,3,5");
    let mut out = Vec::new();
    let mut count: u64 = 0;
    for part in spec.split(',').map(str::trim).filter(|p| !p.is_empty()) {
        let (range, step) = match part.split_once('x') {
            Some((r, s)) => (r, s.parse::<i64>().map_err(|_| bad())?),
            None => (part, 1),
        };
        if step < 1 {
            return Err(bad());
        }
        // A leading '-' is a negative frame, not a range.
        let split = range[1..].find('-').map(|i| i + 1);
        let (a, b) = match split {
            Some(i) => {
                (range[..i].parse::<i64>().map_err(|_| bad())?, range[i + 1..].parse::<i64>().map_err(|_| bad())?)
            }
            None => {
                let f = range.parse::<i64>().map_err(|_| bad())?;
                (f, f)
            }
        };
        if b < a {
            return Err(bad());
        }
        // Counted before anything is expanded.
        count = count.saturating_add((b.abs_diff(a)) / step as u64 + 1);
        if count > MAX_FRAMES {
            return Err(format!(
                "`{spec}` lists {} frames or more; one run takes at most {MAX_FRAMES} — split the range",
                count
            ));
        }
        out.extend((a..=b).step_by(step as usize));
    }
    if out.is_empty() { Err(bad()) } else { Ok(out) }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn patterns_in_the_three_spellings() {
        let p = Pattern::parse("shot/render.####.exr").unwrap();
        assert_eq!(p.path(7), PathBuf::from("shot/render.0007.exr"));
        assert_eq!(Pattern::parse("render.#.exr").unwrap().path(12), PathBuf::from("render.0012.exr"));
        assert_eq!(Pattern::parse("render.@@@.exr").unwrap().path(5), PathBuf::from("render.005.exr"));
        assert_eq!(Pattern::parse("render.%04d.exr").unwrap().path(42), PathBuf::from("render.0042.exr"));
        // Negative frames as printf writes them (the sign counts towards the width).
        assert_eq!(Pattern::parse("n.%04d.exr").unwrap().path(-1), PathBuf::from("n.-001.exr"));
        assert_eq!(Pattern::parse("n.####.exr").unwrap().path(-12), PathBuf::from("n.-012.exr"));
        assert_eq!(Pattern::parse("render.%d.exr").unwrap().path(42), PathBuf::from("render.42.exr"));
        assert!(Pattern::parse("render.0001.exr").is_none());
    }

    #[test]
    fn frame_lists() {
        assert_eq!(parse_frames("1-5").unwrap(), [1, 2, 3, 4, 5]);
        assert_eq!(parse_frames("1-10x4").unwrap(), [1, 5, 9]);
        assert_eq!(parse_frames("1,3,5").unwrap(), [1, 3, 5]);
        assert_eq!(parse_frames("1-2,7,10-12x2").unwrap(), [1, 2, 7, 10, 12]);
        assert_eq!(parse_frames("-2--1").unwrap(), [-2, -1]);
        let t = std::time::Instant::now();
        assert!(parse_frames("1-100000000").unwrap_err().contains("at most 1000000"));
        assert!(parse_frames("1-600000,1-600000").is_err());
        assert!(t.elapsed().as_secs_f64() < 1.0, "refused before expanding");
        assert_eq!(gaps(&[1, 2, 4, 8]), [(3, 3), (5, 7)]);
        for bad in ["", "a-b", "5-1", "1-5x0", "1-5x"] {
            assert!(parse_frames(bad).is_err(), "{bad}");
        }
    }
}

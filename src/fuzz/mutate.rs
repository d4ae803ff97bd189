//! Mutations of valid input files: blind byte edits (flips, truncation, deleted and repeated
//! spans, splices of another file) and structure-aware ones on the tokens of RON, YAML and JSON
//! text (numbers swapped for extremes such as 1e30, -0, NaN or 2⁶⁴, words swapped for other
//! words of the corpus, tokens dropped or repeated, brackets nested deep) and on PNG headers
//! (extreme sizes with a valid checksum, so the decoder reads them).

use rand::Rng;
use rand::seq::IndexedRandom;

/// Numbers a field should survive: zeros, signs, type edges, overflows, non-finite spellings of
/// RON, YAML and JSON, and the sizes that once allocated gigabytes.
const EXTREME_NUMBERS: &[&str] = &[
    "0",
    "-0",
    "-0.0",
    "1",
    "-1",
    "2",
    "255",
    "256",
    "1024",
    "65535",
    "65536",
    "100",
    "0.00001",
    "1e-30",
    "1e30",
    "-1e30",
    "1e308",
    "1e309",
    "-1e309",
    "3.4028235e38",
    "4294967295",
    "4294967296",
    "9223372036854775807",
    "-9223372036854775808",
    "18446744073709551615",
    "18446744073709551616",
    "100000000",
    "1000000000000",
    "NaN",
    "nan",
    "-nan",
    "inf",
    "-inf",
    ".inf",
    "-.inf",
    ".nan",
    "Infinity",
    "-Infinity",
    "0x7fffffff",
    "1_000",
    "00",
    "1.",
    ".5",
    "5e",
    "--1",
];

/// Bytes that end or open structures in the text formats.
const SYNTAX_BYTES: &[u8] = b"()[]{}\"':,;#\n\r\t\\ -.0e";

/// A lexical token of a text file, as a byte range.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    Number,
    Word,
    Quoted,
    Other,
}

/// Applies one to four random mutations to `file`. `others` are the corpus's other files (for
/// splices) and `words` the identifiers and strings seen in the corpus.
pub fn mutate(file: &[u8], others: &[&[u8]], words: &[Vec<u8>], rng: &mut impl Rng) -> Vec<u8> {
    let mut out = file.to_vec();
    for _ in 0..rng.random_range(1..=4) {
        out = mutate_once(&out, others, words, rng);
    }
    out
}

fn mutate_once(data: &[u8], others: &[&[u8]], words: &[Vec<u8>], rng: &mut impl Rng) -> Vec<u8> {
    let mut out = data.to_vec();
    let len = out.len();
    match rng.random_range(0..12) {
        0 if len > 0 => {
            let k = rng.random_range(0..len);
            out[k] ^= 1 << rng.random_range(0..8);
        }
        1 if len > 0 => {
            let k = rng.random_range(0..len);
            out[k] =
                if rng.random_bool(0.5) { rng.random() } else { *SYNTAX_BYTES.choose(rng).expect("bytes") };
        }
        2 => out.truncate(rng.random_range(0..=len)),
        3 if len > 0 => {
            let (a, b) = span(len, rng);
            out.drain(a..b);
        }
        4 if len > 0 => {
            let (a, b) = span(len, rng);
            let copy = out[a..b].to_vec();
            let at = rng.random_range(0..=len);
            out.splice(at..at, copy.iter().cycle().take(copy.len() * rng.random_range(1..=8)).copied());
        }
        5 if !others.is_empty() => {
            let other = others.choose(rng).expect("others");
            let cut = rng.random_range(0..=len);
            let from = rng.random_range(0..=other.len());
            out.truncate(cut);
            out.extend_from_slice(&other[from..]);
        }
        6 => {
            // Deep nesting: parsers must refuse it before their recursion overflows the stack.
            let at = rng.random_range(0..=len);
            let open = *[b"(".as_slice(), b"[", b"{", b"- ", b"Some("].choose(rng).expect("openers");
            let depth = [10, 100, 1_000, 10_000][rng.random_range(0..4)];
            out.splice(at..at, open.iter().copied().cycle().take(open.len() * depth));
        }
        7 => {
            return replace_token(
                data,
                Kind::Number,
                EXTREME_NUMBERS.choose(rng).expect("numbers").as_bytes(),
                rng,
            );
        }
        8 if !words.is_empty() => {
            let word = words.choose(rng).expect("words");
            let kind = if rng.random_bool(0.5) { Kind::Word } else { Kind::Quoted };
            return replace_token(data, kind, word, rng);
        }
        9 => return repeat_or_drop_token(data, rng),
        10 if data.starts_with(PNG_SIGNATURE) => return png_with_size(data, rng),
        _ => {
            return replace_token(
                data,
                Kind::Number,
                EXTREME_NUMBERS.choose(rng).expect("numbers").as_bytes(),
                rng,
            );
        }
    }
    out
}

/// A random non-empty span, short more often than long.
fn span(len: usize, rng: &mut impl Rng) -> (usize, usize) {
    let a = rng.random_range(0..len);
    let max = (len - a).min(if rng.random_bool(0.8) { 16 } else { len });
    (a, a + rng.random_range(1..=max))
}

/// Splits text into tokens; binary data simply yields odd ones.
fn tokens(data: &[u8]) -> Vec<(Kind, usize, usize)> {
    let mut out = Vec::new();
    let mut k = 0;
    while k < data.len() {
        let start = k;
        let c = data[k];
        let kind = if c.is_ascii_digit()
            || (matches!(c, b'-' | b'+' | b'.') && data.get(k + 1).is_some_and(u8::is_ascii_digit))
        {
            k += 1;
            while k < data.len()
                && (data[k].is_ascii_alphanumeric() || matches!(data[k], b'.' | b'_' | b'-' | b'+'))
            {
                k += 1;
            }
            Kind::Number
        } else if c.is_ascii_alphabetic() || c == b'_' {
            while k < data.len() && (data[k].is_ascii_alphanumeric() || data[k] == b'_') {
                k += 1;
            }
            Kind::Word
        } else if c == b'"' {
            k += 1;
            while k < data.len() && data[k] != b'"' && data[k] != b'\n' {
                k += 1 + usize::from(data[k] == b'\\');
            }
            k = (k + 1).min(data.len());
            Kind::Quoted
        } else {
            k += 1;
            Kind::Other
        };
        if !c.is_ascii_whitespace() {
            out.push((kind, start, k));
        }
    }
    out
}

/// Identifiers and quoted strings of `files`: field names, system names, paths, enum variants.
pub fn corpus_words(files: &[&[u8]]) -> Vec<Vec<u8>> {
    let mut words: Vec<Vec<u8>> = files
        .iter()
        .flat_map(|data| {
            tokens(data)
                .into_iter()
                .filter(|(kind, a, b)| matches!(kind, Kind::Word | Kind::Quoted) && b - a <= 64)
                .map(|(_, a, b)| data[a..b].to_vec())
        })
        .collect();
    words.sort();
    words.dedup();
    words
}

/// Replaces one random token of `kind` (any token if there is none) by `with`.
fn replace_token(data: &[u8], kind: Kind, with: &[u8], rng: &mut impl Rng) -> Vec<u8> {
    let all = tokens(data);
    let of_kind: Vec<_> = all.iter().copied().filter(|t| t.0 == kind).collect();
    let pool = if of_kind.is_empty() { &all } else { &of_kind };
    let Some(&(_, a, b)) = pool.choose(rng) else { return with.to_vec() };
    [&data[..a], with, &data[b..]].concat()
}

/// Drops one token, or repeats it up to a thousand times.
fn repeat_or_drop_token(data: &[u8], rng: &mut impl Rng) -> Vec<u8> {
    let all = tokens(data);
    let Some(&(_, a, b)) = all.choose(rng) else { return data.to_vec() };
    let times = if rng.random_bool(0.5) { 0 } else { [2, 3, 10, 1000][rng.random_range(0..4)] };
    [&data[..a], &data[a..b].repeat(times), &data[b..]].concat()
}

const PNG_SIGNATURE: &[u8] = b"\x89PNG\r\n\x1a\n";

/// A PNG whose header claims an extreme width or height, with the header's CRC fixed so the
/// decoder gets as far as believing it.
fn png_with_size(data: &[u8], rng: &mut impl Rng) -> Vec<u8> {
    // Signature (8), length (4), "IHDR" (4), width (4), height (4), 5 more bytes, CRC (4).
    const IHDR: usize = 8;
    if data.len() < IHDR + 25 || &data[IHDR + 4..IHDR + 8] != b"IHDR" {
        return data.to_vec();
    }
    let mut out = data.to_vec();
    let sizes = [0u32, 1, 10_001, 65_535, 100_000, 1 << 24, u32::MAX, 2_147_483_647];
    let field = IHDR + 8 + 4 * rng.random_range(0..2);
    out[field..field + 4].copy_from_slice(&sizes.choose(rng).expect("sizes").to_be_bytes());
    let crc = crc32fast::hash(&out[IHDR + 4..IHDR + 21]);
    out[IHDR + 21..IHDR + 25].copy_from_slice(&crc.to_be_bytes());
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn tokens_split_ron_into_numbers_words_and_strings() {
        let text = br#"Scene(count: -2, path: "a b.yaml", x: 1e-3)"#;
        let kinds: Vec<_> = tokens(text).into_iter().map(|(k, a, b)| (k, &text[a..b])).collect();
        assert!(kinds.contains(&(Kind::Number, b"-2".as_slice())), "{kinds:?}");
        assert!(kinds.contains(&(Kind::Number, b"1e-3".as_slice())), "{kinds:?}");
        assert!(kinds.contains(&(Kind::Quoted, br#""a b.yaml""#.as_slice())), "{kinds:?}");
        assert!(kinds.contains(&(Kind::Word, b"Scene".as_slice())), "{kinds:?}");
    }

    #[test]
    fn number_replacement_keeps_the_rest_of_the_text() {
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(1);
        let out = replace_token(b"robots_per_map: 4,", Kind::Number, b"100000000", &mut rng);
        assert_eq!(out, b"robots_per_map: 100000000,");
    }

    #[test]
    fn png_size_mutation_keeps_a_valid_header_checksum() {
        let mut png = Vec::new();
        image::GrayImage::new(2, 2)
            .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
            .expect("encode");
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(3);
        let out = png_with_size(&png, &mut rng);
        assert_ne!(out[16..24], png[16..24], "width or height changed");
        let crc = u32::from_be_bytes(out[29..33].try_into().expect("4 bytes"));
        assert_eq!(crc, crc32fast::hash(&out[12..29]), "the header's CRC matches its new size");
    }

    #[test]
    fn mutations_are_deterministic_per_seed() {
        let words = corpus_words(&[b"Scene(maps: Procedural(split: seen))"]);
        let run = |seed| {
            let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(seed);
            mutate(b"Scene(robots_per_map: 4, seed: 7)", &[b"x: 1"], &words, &mut rng)
        };
        assert_eq!(run(5), run(5));
        assert!((0..20).any(|s| run(s) != run(5)), "different seeds give different inputs");
    }
}

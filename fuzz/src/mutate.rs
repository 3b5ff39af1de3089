//! Structure-aware byte mutations of text seeds (TOML, XML, JSON, whitespace tables).

use rand::Rng;
use rand_chacha::ChaCha8Rng;

/// Numbers that sit on or past a bound somewhere: overflow, NaN, infinities, negative zero,
/// subnormals, the edges of `i64`/`u64`/`u32`, and values just past the SDK's input limits.
pub const EXTREME_NUMBERS: &[&str] = &[
    "1e300",
    "-1e300",
    "1e-300",
    "5e-324",
    "NaN",
    "nan",
    "-nan",
    "inf",
    "-inf",
    "+inf",
    "-0",
    "-0.0",
    "0",
    "0.0",
    "-1",
    "1",
    "2",
    "9223372036854775807",
    "9223372036854775808",
    "-9223372036854775808",
    "-9223372036854775809",
    "18446744073709551615",
    "18446744073709551616",
    "4294967295",
    "4294967296",
    "2147483648",
    "65536",
    "1e6",
    "1000001",
    "86400",
    "86401",
    "3600.0001",
    "1e19",
    "0x7fffffff",
    "1_000_000_000_000",
    "0.1e-7",
    "1e309",
];

/// Values of the wrong type for a TOML or JSON key.
const WRONG_TYPES: &[&str] = &[
    "\"x\"",
    "\"\"",
    "[]",
    "{}",
    "true",
    "false",
    "null",
    "[1, \"a\"]",
    "{ a = 1 }",
    "{\"a\": 1}",
    "[[]]",
    "1979-05-27T07:32:00Z",
    "'''x'''",
];

/// One to four stacked mutations of `seed`; `others` are spliced from.
pub fn mutate(rng: &mut ChaCha8Rng, seed: &[u8], others: &[Vec<u8>]) -> Vec<u8> {
    let mut b = seed.to_vec();
    let n = 1 + rng.random_range(0..4);
    for _ in 0..n {
        mutate_once(rng, &mut b, others);
    }
    b
}

fn pos(rng: &mut ChaCha8Rng, b: &[u8]) -> usize {
    rng.random_range(0..=b.len())
}

fn mutate_once(rng: &mut ChaCha8Rng, b: &mut Vec<u8>, others: &[Vec<u8>]) {
    match rng.random_range(0..16) {
        0 if !b.is_empty() => {
            let i = rng.random_range(0..b.len());
            b[i] ^= 1 << rng.random_range(0..8);
        }
        1 if !b.is_empty() => {
            let i = rng.random_range(0..b.len());
            b[i] = *pick(
                rng,
                &[
                    0u8, b' ', b'\n', b'"', b'\'', b'[', b']', b'{', b'}', b'=', b',', b':', b'<',
                    b'>', b'/', b'#', b'\\', b'-', b'.', b'e', 0xff, 0x80,
                ],
            );
        }
        2 => {
            let i = pos(rng, b);
            let n = rng.random_range(1..16);
            let bytes: Vec<u8> = (0..n).map(|_| rng.random()).collect();
            b.splice(i..i, bytes);
        }
        3 if !b.is_empty() => {
            let i = rng.random_range(0..b.len());
            let n = rng.random_range(1..=(b.len() - i).min(64));
            b.drain(i..i + n);
        }
        4 => {
            let i = pos(rng, b);
            b.truncate(i);
        }
        5..=7 => replace_number(rng, b),
        8 => replace_value(rng, b),
        9 => duplicate_line(rng, b),
        10 => drop_or_swap_line(rng, b),
        11 => nest(rng, b),
        12 => {
            let i = pos(rng, b);
            let n = *pick(rng, &[256usize, 4096, 70_000, 300_000]);
            let c = *pick(rng, b"a9 \"\n\t");
            b.splice(i..i, std::iter::repeat_n(c, n));
        }
        13 if !others.is_empty() => {
            let o = &others[rng.random_range(0..others.len())];
            if !o.is_empty() {
                let s = rng.random_range(0..o.len());
                let e = rng.random_range(s..=o.len().min(s + 512));
                let i = pos(rng, b);
                b.splice(i..i, o[s..e].iter().copied());
            }
        }
        14 => {
            // A number inserted anywhere (an extra column, a second value).
            let i = pos(rng, b);
            let sep = *pick(rng, &[" ", "\n", ",", "=", ""]);
            let s = format!("{sep}{}", pick(rng, EXTREME_NUMBERS));
            b.splice(i..i, s.into_bytes());
        }
        _ => {
            // Repeat a short chunk many times (many rows, many keys).
            if b.is_empty() {
                return;
            }
            let s = rng.random_range(0..b.len());
            let e = (s + rng.random_range(1..80)).min(b.len());
            let chunk = b[s..e].to_vec();
            let times = *pick(rng, &[2usize, 10, 100, 1000]);
            let i = pos(rng, b);
            let rep: Vec<u8> = chunk
                .iter()
                .copied()
                .cycle()
                .take(chunk.len() * times)
                .collect();
            b.splice(i..i, rep);
        }
    }
}

fn pick<'a, T>(rng: &mut ChaCha8Rng, xs: &'a [T]) -> &'a T {
    &xs[rng.random_range(0..xs.len())]
}

/// Spans of number-like tokens (`-1.5e3`, `42`).
fn numbers(b: &[u8]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < b.len() {
        let starts =
            b[i].is_ascii_digit() || (b[i] == b'-' && b.get(i + 1).is_some_and(u8::is_ascii_digit));
        if starts && (i == 0 || !b[i - 1].is_ascii_alphanumeric()) {
            let s = i;
            i += 1;
            while i < b.len()
                && (b[i].is_ascii_digit()
                    || matches!(b[i], b'.' | b'e' | b'E' | b'+' | b'-' | b'_'))
            {
                i += 1;
            }
            out.push((s, i));
        } else {
            i += 1;
        }
    }
    out
}

fn replace_number(rng: &mut ChaCha8Rng, b: &mut Vec<u8>) {
    let spans = numbers(b);
    if spans.is_empty() {
        return;
    }
    let (s, e) = spans[rng.random_range(0..spans.len())];
    let with = pick(rng, EXTREME_NUMBERS);
    b.splice(s..e, with.bytes());
}

/// Replaces the value after a `=` or `:` with one of another type.
fn replace_value(rng: &mut ChaCha8Rng, b: &mut Vec<u8>) {
    let seps: Vec<usize> = b
        .iter()
        .enumerate()
        .filter(|(_, c)| matches!(c, b'=' | b':'))
        .map(|(i, _)| i)
        .collect();
    if seps.is_empty() {
        return;
    }
    let s = seps[rng.random_range(0..seps.len())] + 1;
    let e = b[s..]
        .iter()
        .position(|c| matches!(c, b'\n' | b','))
        .map_or(b.len(), |k| s + k);
    let with = format!(" {}", pick(rng, WRONG_TYPES));
    b.splice(s..e, with.into_bytes());
}

fn line_spans(b: &[u8]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut s = 0;
    for (i, c) in b.iter().enumerate() {
        if *c == b'\n' {
            out.push((s, i + 1));
            s = i + 1;
        }
    }
    if s < b.len() {
        out.push((s, b.len()));
    }
    out
}

/// Copies a line elsewhere (a duplicated key, a repeated row).
fn duplicate_line(rng: &mut ChaCha8Rng, b: &mut Vec<u8>) {
    let lines = line_spans(b);
    if lines.is_empty() {
        return;
    }
    let (s, e) = lines[rng.random_range(0..lines.len())];
    let mut line = b[s..e].to_vec();
    if line.last() != Some(&b'\n') {
        line.push(b'\n');
    }
    let at = lines[rng.random_range(0..lines.len())].0;
    b.splice(at..at, line);
}

fn drop_or_swap_line(rng: &mut ChaCha8Rng, b: &mut Vec<u8>) {
    let lines = line_spans(b);
    if lines.len() < 2 {
        return;
    }
    let i = rng.random_range(0..lines.len());
    let (s, e) = lines[i];
    if rng.random_bool(0.5) {
        b.drain(s..e);
    } else {
        let j = rng.random_range(0..lines.len());
        let (a, z) = (lines[i.min(j)], lines[i.max(j)]);
        if a == z {
            return;
        }
        let mut out = Vec::with_capacity(b.len());
        out.extend_from_slice(&b[..a.0]);
        out.extend_from_slice(&b[z.0..z.1]);
        out.extend_from_slice(&b[a.1..z.0]);
        out.extend_from_slice(&b[a.0..a.1]);
        out.extend_from_slice(&b[z.1..]);
        *b = out;
    }
}

/// Deep nesting of the format's brackets (arrays, inline tables, XML elements, dotted keys).
fn nest(rng: &mut ChaCha8Rng, b: &mut Vec<u8>) {
    let depth = *pick(rng, &[8usize, 65, 129, 1000, 20_000]);
    let (open, close): (&str, &str) = *pick(
        rng,
        &[
            ("[", "]"),
            ("{", "}"),
            ("{\"a\":", "}"),
            ("{ a = ", " }"),
            ("<link>", "</link>"),
            ("<a>", "</a>"),
            ("a.", "b = 1"),
            ("[[", "]]"),
        ],
    );
    let i = pos(rng, b);
    let mut s = open.repeat(depth);
    if rng.random_bool(0.7) {
        s.push_str(&close.repeat(depth));
    }
    b.splice(i..i, s.into_bytes());
}

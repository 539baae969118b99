//! Where in a TOML document a key is, and which key a byte offset belongs to, so that every
//! error can name the key and its line.

use toml::de::{DeTable, DeValue};

/// 1-based line of byte `offset` in `doc`.
pub fn line_of(doc: &str, offset: usize) -> usize {
    let end = offset.min(doc.len());
    doc.as_bytes()[..end]
        .iter()
        .filter(|&&b| b == b'\n')
        .count()
        + 1
}

/// One step of a key path: a table key or an array index.
#[derive(Debug, Clone, PartialEq)]
enum Segment {
    Key(String),
    Index(usize),
}

/// Splits `bodies[0].pieces[2].box` into its segments.
fn segments(path: &str) -> Vec<Segment> {
    let mut out = Vec::new();
    for part in path.split('.') {
        let (name, rest) = match part.find('[') {
            Some(i) => (&part[..i], &part[i..]),
            None => (part, ""),
        };
        if !name.is_empty() {
            out.push(Segment::Key(name.to_string()));
        }
        for idx in rest.split('[').filter(|s| !s.is_empty()) {
            if let Ok(i) = idx.trim_end_matches(']').parse() {
                out.push(Segment::Index(i));
            }
        }
    }
    out
}

/// The line where the deepest existing prefix of `path` is written (the key itself if it is in
/// the file, otherwise its table's header). `None` if the document does not parse.
pub fn line_of_key(doc: &str, path: &str) -> Option<usize> {
    let root = DeTable::parse(doc).ok()?;
    let mut best: Option<usize> = None;
    let mut table: Option<&DeTable<'_>> = Some(root.get_ref());
    let mut value: Option<&DeValue<'_>> = None;
    for seg in segments(path) {
        let next = match (&seg, table, value) {
            (Segment::Key(k), Some(t), _) => {
                t.iter()
                    .find(|(key, _)| key.get_ref() == k)
                    .map(|(key, v)| {
                        best = Some(key.span().start);
                        v
                    })
            }
            (Segment::Index(i), _, Some(DeValue::Array(a))) => a.get(*i).inspect(|v| {
                best = Some(v.span().start);
            }),
            _ => None,
        };
        let Some(v) = next else { break };
        value = Some(v.get_ref());
        table = match v.get_ref() {
            DeValue::Table(t) => Some(t),
            _ => None,
        };
    }
    best.map(|o| line_of(doc, o))
}

/// The key path (e.g. `bodies[0].mass`) of the innermost key whose key or value covers `offset`.
pub fn key_at(doc: &str, offset: usize) -> Option<String> {
    let root = DeTable::parse(doc).ok()?;
    let mut path = String::new();
    let mut found = false;
    descend_table(root.get_ref(), offset, &mut path, &mut found);
    found.then_some(path)
}

fn descend_table(t: &DeTable<'_>, offset: usize, path: &mut String, found: &mut bool) {
    for (key, v) in t.iter() {
        let ks = key.span();
        let vs = v.span();
        let covers = (ks.start <= offset && offset < ks.end.max(ks.start + 1))
            || (vs.start <= offset && offset < vs.end.max(vs.start + 1))
            || contains_deep(v.get_ref(), offset);
        if covers {
            if !path.is_empty() {
                path.push('.');
            }
            path.push_str(key.get_ref());
            *found = true;
            descend_value(v.get_ref(), offset, path, found);
            return;
        }
    }
}

fn descend_value(v: &DeValue<'_>, offset: usize, path: &mut String, found: &mut bool) {
    match v {
        DeValue::Table(t) => descend_table(t, offset, path, found),
        DeValue::Array(a) => {
            for (i, item) in a.iter().enumerate() {
                let s = item.span();
                if (s.start <= offset && offset < s.end) || contains_deep(item.get_ref(), offset) {
                    path.push_str(&format!("[{i}]"));
                    descend_value(item.get_ref(), offset, path, found);
                    return;
                }
            }
        }
        _ => {}
    }
}

/// Whether any key or value below `v` covers `offset` (tables of an array of tables are not
/// contiguous in the text, so spans of the container alone do not tell).
fn contains_deep(v: &DeValue<'_>, offset: usize) -> bool {
    match v {
        DeValue::Table(t) => t.iter().any(|(k, x)| {
            let (ks, vs) = (k.span(), x.span());
            (ks.start <= offset && offset < ks.end)
                || (vs.start <= offset && offset < vs.end)
                || contains_deep(x.get_ref(), offset)
        }),
        DeValue::Array(a) => a.iter().any(|x| {
            let s = x.span();
            (s.start <= offset && offset < s.end) || contains_deep(x.get_ref(), offset)
        }),
        _ => false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const DOC: &str = "name = \"x\"\n\n[simulation]\nh = 0.01\n\n[[bodies]]\nmass = 1\n\n[[bodies]]\nmass = -2\n[[bodies.pieces]]\nbox = [1, 2, 3]\n";

    #[test]
    fn finds_lines_of_keys() {
        assert_eq!(line_of_key(DOC, "simulation.h"), Some(4));
        assert_eq!(line_of_key(DOC, "bodies[1].mass"), Some(10));
        assert_eq!(line_of_key(DOC, "bodies[1].pieces[0].box"), Some(12));
        // A missing key falls back to its table.
        assert_eq!(line_of_key(DOC, "bodies[0].inertia"), Some(6));
    }

    #[test]
    fn finds_keys_at_offsets() {
        let off = DOC.find("-2").expect("present");
        assert_eq!(key_at(DOC, off).as_deref(), Some("bodies[1].mass"));
        let off = DOC.find("box").expect("present");
        assert_eq!(key_at(DOC, off).as_deref(), Some("bodies[1].pieces[0].box"));
    }
}

//! The documents stay usable: README.md and ARCHITECTURE.md within their size budgets,
//! ARCHITECTURE.md with a contents list, README's count of hostile-input cases that of the
//! generated table, and every relative link in the project's markdown (README, ARCHITECTURE,
//! CONTRIBUTING, CHANGELOG, `docs/**`, `plugins/*/README.md`) pointing at a file that exists
//! and, for `#anchor` into a markdown file, at a heading it has. Anchors follow GitHub's rule:
//! the heading's text lowercased, punctuation dropped (letters, digits, `-` and `_` kept),
//! spaces turned into `-`, and `-1`, `-2`, ... appended to repeats.

use human2nav_integration_tests::workspace_root;
use std::collections::HashSet;
use std::fs;
use std::path::{Path, PathBuf};

/// README.md's budget in bytes.
const README_MAX_BYTES: u64 = 10_240;
/// ARCHITECTURE.md's budget in bytes.
const ARCHITECTURE_MAX_BYTES: u64 = 30_720;

fn size_of(name: &str) -> u64 {
    let path = workspace_root().join(name);
    fs::metadata(&path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .len()
}

fn text_of(name: &str) -> String {
    let path = workspace_root().join(name);
    fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

#[test]
fn readme_stays_within_its_budget() {
    let bytes = size_of("README.md");
    assert!(
        bytes <= README_MAX_BYTES,
        "README.md is {bytes} bytes, over its budget of {README_MAX_BYTES}: move results to \
         docs/experiments and details to ARCHITECTURE.md or docs/guide"
    );
}

#[test]
fn architecture_stays_within_its_budget() {
    let bytes = size_of("ARCHITECTURE.md");
    assert!(
        bytes <= ARCHITECTURE_MAX_BYTES,
        "ARCHITECTURE.md is {bytes} bytes, over its budget of {ARCHITECTURE_MAX_BYTES}: \
         measured results belong in docs/experiments, linked from here"
    );
}

/// The number README.md gives for the hostile-input table: its `| total | N |` row.
#[test]
fn readme_gives_the_hostile_input_tables_count() {
    let table = text_of("docs/hostile-inputs.md");
    let total = table
        .lines()
        .find_map(|l| l.strip_prefix("| total | "))
        .and_then(|rest| rest.split(' ').next())
        .expect("docs/hostile-inputs.md has a `| total | N |` row");
    let readme = text_of("README.md");
    let stated = readme
        .split("(docs/hostile-inputs.md) lists ")
        .nth(1)
        .and_then(|rest| rest.split(' ').next())
        .expect("README.md says how many cases docs/hostile-inputs.md lists");
    assert_eq!(
        stated, total,
        "README.md says docs/hostile-inputs.md lists {stated} cases; its table's total is {total}"
    );
}

#[test]
fn architecture_has_a_contents_list_of_its_sections() {
    let path = workspace_root().join("ARCHITECTURE.md");
    let text = fs::read_to_string(&path).unwrap();
    let anchors = heading_anchors(&text);
    let lines: Vec<&str> = text.lines().collect();
    let start = lines
        .iter()
        .position(|l| l.trim() == "## Contents")
        .expect("ARCHITECTURE.md has no `## Contents` heading");
    let listed: Vec<String> = lines[start + 1..]
        .iter()
        .take_while(|l| !l.starts_with("## "))
        .flat_map(|l| links(l))
        .filter_map(|target| target.strip_prefix('#').map(str::to_string))
        .collect();
    assert!(!listed.is_empty(), "the contents list links no section");
    for anchor in &listed {
        assert!(
            anchors.contains(anchor),
            "the contents list links #{anchor}, which is no heading"
        );
    }
    // Every `##` section after the contents is listed.
    for line in &lines[start + 1..] {
        if let Some(title) = line.strip_prefix("## ") {
            let slug = slugify(title);
            assert!(
                listed.contains(&slug),
                "section `{title}` (#{slug}) is missing from the contents list"
            );
        }
    }
}

#[test]
fn relative_links_point_at_existing_files_and_headings() {
    let root = workspace_root();
    let mut files: Vec<PathBuf> = [
        "README.md",
        "ARCHITECTURE.md",
        "CONTRIBUTING.md",
        "CHANGELOG.md",
    ]
    .iter()
    .map(|name| root.join(name))
    .filter(|path| path.is_file())
    .collect();
    markdown_under(&root.join("docs"), &mut files);
    for entry in fs::read_dir(root.join("plugins")).unwrap() {
        let readme = entry.unwrap().path().join("README.md");
        if readme.is_file() {
            files.push(readme);
        }
    }
    assert!(files.len() > 5, "found only {} markdown files", files.len());

    let mut broken = Vec::new();
    let mut checked = 0;
    for file in &files {
        let text = fs::read_to_string(file).unwrap();
        let dir = file.parent().unwrap();
        for target in links(&text) {
            if is_external(&target) {
                continue;
            }
            checked += 1;
            let (path_part, anchor) = match target.split_once('#') {
                Some((p, a)) => (p, Some(a)),
                None => (target.as_str(), None),
            };
            let dest = if path_part.is_empty() {
                file.clone()
            } else {
                dir.join(path_part)
            };
            let shown = file.strip_prefix(&root).unwrap_or(file).display();
            if !dest.exists() {
                broken.push(format!("{shown}: `{target}`: no such file"));
                continue;
            }
            let Some(anchor) = anchor else { continue };
            if dest.extension().is_none_or(|e| e != "md") {
                continue;
            }
            let anchors = heading_anchors(&fs::read_to_string(&dest).unwrap());
            if !anchors.contains(anchor) {
                broken.push(format!(
                    "{shown}: `{target}`: no heading with anchor #{anchor}"
                ));
            }
        }
    }
    assert!(checked > 50, "checked only {checked} links");
    assert!(broken.is_empty(), "broken links:\n{}", broken.join("\n"));
}

#[test]
fn the_slug_rule_matches_github() {
    assert_eq!(slugify("Where do I change X"), "where-do-i-change-x");
    assert_eq!(
        slugify("The planning call, stage by stage"),
        "the-planning-call-stage-by-stage"
    );
    assert_eq!(slugify("The `human2nav` command"), "the-human2nav-command");
    assert_eq!(
        slugify("Output folders, checkpoints and caches"),
        "output-folders-checkpoints-and-caches"
    );
    assert_eq!(slugify("[Unreleased]"), "unreleased");
    assert_eq!(slugify("[0.1.0] - 2026-12-04"), "010---2026-12-04");
    assert_eq!(slugify("B → C: personal space"), "b--c-personal-space");
    let anchors = heading_anchors("# A\n## A\n```\n# not a heading\n```\n### A\n");
    assert!(anchors.contains("a") && anchors.contains("a-1") && anchors.contains("a-2"));
    assert!(!anchors.contains("not-a-heading"));
}

#[test]
fn links_are_found_outside_code_only() {
    let text = "see [a](x.md) and `[b](y.md)`\n```\n[c](z.md)\n```\n![p](i.png \"t\") [d](<w.md>)";
    assert_eq!(links(text), ["x.md", "i.png", "w.md"]);
}

/// Every `.md` file under `dir`, recursively.
fn markdown_under(dir: &Path, out: &mut Vec<PathBuf>) {
    let entries = fs::read_dir(dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
    for entry in entries {
        let path = entry.expect("a directory entry").path();
        if path.is_dir() {
            markdown_under(&path, out);
        } else if path.extension().is_some_and(|e| e == "md") {
            out.push(path);
        }
    }
}

fn is_external(target: &str) -> bool {
    target.contains("://") || target.starts_with("mailto:")
}

/// The text with fenced code blocks removed and inline code spans blanked.
fn prose(text: &str) -> String {
    let mut out = String::new();
    let mut fenced = false;
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            fenced = !fenced;
            out.push('\n');
            continue;
        }
        if fenced {
            out.push('\n');
            continue;
        }
        let mut in_code = false;
        for ch in line.chars() {
            if ch == '`' {
                in_code = !in_code;
            } else if !in_code {
                out.push(ch);
            }
        }
        out.push('\n');
    }
    out
}

/// The destinations of the inline links and images `[text](dest)` outside code.
fn links(text: &str) -> Vec<String> {
    let text = prose(text);
    let mut out = Vec::new();
    let mut rest = text.as_str();
    while let Some(i) = rest.find("](") {
        rest = &rest[i + 2..];
        let Some(end) = rest.find(')') else { break };
        let inner = rest[..end].trim();
        let dest = if let Some(angled) = inner.strip_prefix('<') {
            angled.split('>').next().unwrap_or("")
        } else {
            inner.split_whitespace().next().unwrap_or("")
        };
        if !dest.is_empty() {
            out.push(dest.to_string());
        }
        rest = &rest[end..];
    }
    out
}

/// The anchors of a markdown file's ATX headings (`#` to `######`), outside fenced code.
fn heading_anchors(text: &str) -> HashSet<String> {
    let mut anchors = HashSet::new();
    let mut fenced = false;
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            fenced = !fenced;
            continue;
        }
        if fenced {
            continue;
        }
        let hashes = line.chars().take_while(|&c| c == '#').count();
        if !(1..=6).contains(&hashes) || !line[hashes..].starts_with(' ') {
            continue;
        }
        let base = slugify(line[hashes..].trim());
        let mut anchor = base.clone();
        let mut n = 0;
        while anchors.contains(&anchor) {
            n += 1;
            anchor = format!("{base}-{n}");
        }
        anchors.insert(anchor);
    }
    anchors
}

/// GitHub's anchor for a heading: link syntax reduced to its text, then lowercase letters,
/// digits, `-` and `_` kept, spaces turned into `-`, everything else dropped.
fn slugify(heading: &str) -> String {
    let mut text = String::new();
    let mut rest = heading;
    // `[text](dest)` counts as `text`.
    while let Some(open) = rest.find('[') {
        let after = &rest[open + 1..];
        match (after.find("]("), after.find(')')) {
            (Some(close), Some(paren)) if close < paren => {
                text.push_str(&rest[..open]);
                text.push_str(&after[..close]);
                rest = &after[paren + 1..];
            }
            _ => {
                text.push_str(&rest[..=open]);
                rest = after;
            }
        }
    }
    text.push_str(rest);
    text.chars()
        .filter_map(|c| {
            if c.is_alphanumeric() || c == '-' || c == '_' {
                Some(c.to_lowercase().collect::<String>())
            } else if c == ' ' {
                Some("-".to_string())
            } else {
                None
            }
        })
        .collect()
}

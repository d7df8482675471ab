//! Every relative link in the README and the docs pages reaches something: the file (or folder)
//! it names exists, and an anchor (`page.md#section`, `#section`) names a heading of that page,
//! spelt as GitHub spells heading anchors. Links inside code blocks and code spans are not links.

use std::collections::HashMap;
use std::fs;
use std::path::{Path, PathBuf};

/// The markdown files whose links are checked: the README, docs/, and the READMEs of the
/// package folders a reader reaches from them.
fn pages(root: &Path) -> Vec<PathBuf> {
    let mut pages = vec![root.join("README.md")];
    for dir in ["docs", "python", "viewer", "examples/slurm", "examples/kubernetes", "examples/ray", "tests/fixtures/nerf-pytorch"] {
        let Ok(entries) = fs::read_dir(root.join(dir)) else { continue };
        let mut found: Vec<PathBuf> = entries.map(|e| e.unwrap().path()).filter(|p| p.extension().is_some_and(|e| e == "md")).collect();
        found.sort();
        pages.extend(found);
    }
    pages
}

/// The text outside fenced code blocks and code spans, line by line (so line numbers hold).
fn prose(text: &str) -> Vec<String> {
    let mut fenced = false;
    text.lines()
        .map(|line| {
            if line.trim_start().starts_with("```") {
                fenced = !fenced;
                return String::new();
            }
            if fenced {
                return String::new();
            }
            // Drop code spans: odd-numbered pieces between backticks.
            line.split('`').step_by(2).collect::<Vec<_>>().join(" ")
        })
        .collect()
}

/// The targets of `[text](target)` and `![alt](target)` on a line.
fn link_targets(line: &str) -> Vec<String> {
    let mut targets = Vec::new();
    let mut rest = line;
    while let Some(at) = rest.find("](") {
        let after = &rest[at + 2..];
        let Some(end) = after.find(')') else { break };
        // `[a](b "title")`: the target is the first word.
        let target = after[..end].split_whitespace().next().unwrap_or("");
        targets.push(target.to_string());
        rest = &after[end..];
    }
    targets
}

/// GitHub's anchor for a heading: lower case, punctuation dropped (letters, digits, `-` and `_`
/// stay), spaces become hyphens.
fn slug(heading: &str) -> String {
    heading
        .trim()
        .to_lowercase()
        .chars()
        .filter(|c| c.is_alphanumeric() || *c == '-' || *c == '_' || *c == ' ')
        .map(|c| if c == ' ' { '-' } else { c })
        .collect()
}

/// Every anchor a page defines: its headings' slugs, a repeated one with `-1`, `-2`, … as
/// GitHub numbers them.
fn anchors(text: &str) -> Vec<String> {
    let mut seen: HashMap<String, usize> = HashMap::new();
    let mut fenced = false;
    let mut out = Vec::new();
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            fenced = !fenced;
            continue;
        }
        let hashes = line.chars().take_while(|&c| c == '#').count();
        if fenced || hashes == 0 || hashes > 6 || !line[hashes..].starts_with(' ') {
            continue;
        }
        let base = slug(&line[hashes..].replace('`', ""));
        let count = seen.entry(base.clone()).or_insert(0);
        out.push(if *count == 0 { base.clone() } else { format!("{base}-{count}") });
        *count += 1;
    }
    out
}

/// The broken links of one page: "page:line: target: why".
fn broken_links(page: &Path) -> Vec<String> {
    let text = fs::read_to_string(page).unwrap();
    let mut broken = Vec::new();
    for (number, line) in prose(&text).iter().enumerate() {
        for target in link_targets(line) {
            if target.is_empty() || target.contains("://") || target.starts_with("mailto:") {
                continue;
            }
            let (path, anchor) = match target.split_once('#') {
                Some((path, anchor)) => (path, Some(anchor)),
                None => (target.as_str(), None),
            };
            let file = if path.is_empty() { page.to_path_buf() } else { page.parent().unwrap().join(path) };
            let problem = if !file.exists() {
                Some("no such file".to_string())
            } else if let Some(anchor) = anchor {
                let defined = file.extension().is_some_and(|e| e == "md") && anchors(&fs::read_to_string(&file).unwrap()).iter().any(|a| a == anchor);
                (!defined).then(|| format!("no heading with the anchor #{anchor} in {}", file.display()))
            } else {
                None
            };
            if let Some(problem) = problem {
                broken.push(format!("{}:{}: {target}: {problem}", page.display(), number + 1));
            }
        }
    }
    broken
}

#[test]
fn every_relative_link_in_the_readme_and_docs_reaches_its_target() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let pages = pages(root);
    assert!(pages.len() > 10, "{pages:?}");
    let mut links = 0;
    let mut broken = Vec::new();
    for page in &pages {
        links += prose(&fs::read_to_string(page).unwrap()).iter().map(|l| link_targets(l).len()).sum::<usize>();
        broken.extend(broken_links(page));
    }
    assert!(links > 50, "only {links} links found: is the scanner reading the pages?");
    assert!(broken.is_empty(), "broken links:\n{}", broken.join("\n"));
}

#[test]
fn the_readme_stays_a_front_door() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let readme = fs::read_to_string(root.join("README.md")).unwrap();
    let lines = readme.lines().count();
    assert!(lines <= 160, "README.md has {lines} lines: move reference material to docs/");
    // The two commands CI and a new user run.
    for command in ["bash scripts/demo.sh", "bash scripts/test.sh"] {
        assert!(readme.contains(command), "README.md lost `{command}`");
    }
    let ci = fs::read_to_string(root.join(".ci/run")).unwrap();
    assert!(ci.contains("scripts/test.sh"), ".ci/run no longer runs the README's test command");
}

#[test]
fn the_checker_finds_what_is_broken_and_spells_anchors_as_github() {
    assert_eq!(slug("The `nerf-render` command (onnxruntime, no burn)".replace('`', "").as_str()), "the-nerf-render-command-onnxruntime-no-burn");
    assert_eq!(slug("Backgrounds"), "backgrounds");
    assert_eq!(slug("Accuracy on the generated scene"), "accuracy-on-the-generated-scene");
    assert_eq!(slug("Shards: `--shard i/n`".replace('`', "").as_str()), "shards---shard-in");
    assert_eq!(anchors("# A\n## B\n```\n# not a heading\n```\n## B\n#nope\n"), ["a", "b", "b-1"]);
    assert_eq!(link_targets("see [x](a.md#b) and ![p](img.png \"t\") and [y](https://e.org)"), ["a.md#b", "img.png", "https://e.org"]);
    assert_eq!(prose("a `[x](gone.md)` b\n```\n[y](gone.md)\n```\n[z](here.md)"), ["a   b", "", "", "", "[z](here.md)"]);

    let dir = tempfile::tempdir().unwrap();
    fs::write(dir.path().join("here.md"), "# Here\n## Part two\n").unwrap();
    let page = dir.path().join("page.md");
    fs::write(&page, "[ok](here.md) [ok](here.md#part-two) [ok](#top) [bad](gone.md) [bad](here.md#nothing) `[code](gone.md)`\n# Top\n").unwrap();
    let broken = broken_links(&page);
    assert_eq!(broken.len(), 2, "{broken:?}");
    assert!(broken[0].contains("gone.md: no such file") && broken[1].contains("#nothing"), "{broken:?}");
}

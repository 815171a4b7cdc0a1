//! The architecture invariants of ARCHITECTURE.md ("Layers and rules"),
//! checked on the manifests and on the sources' import paths.
//!
//! The layers are crates: `lightwire-protocol` and `lightwire-adapter` at
//! the bottom, then `lightwire-scene`, `lightwire-solve`, and
//! `lightwire-server` on top; `lightwire-client` beside the server. A crate
//! that does not depend on another cannot import it, so the compiler
//! enforces most of the layering once the manifests say the right thing;
//! the first test holds the manifests to it. Within a crate, imports are
//! parsed (every `use` tree expanded, every `crate::`/`super::`/`self::`
//! path in code resolved to the file that defines the item, following
//! re-exports), and the rules below are checked on those paths, not on
//! substrings: a comment or a string that names a module breaks nothing,
//! an import through a re-export or a glob still counts.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// The workspace root (this crate lives in `server/`).
fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("server/ has a parent")
        .to_path_buf()
}

/// The dependency names of a manifest's `[dependencies]` table.
fn dependencies(crate_dir: &str) -> Vec<String> {
    let path = root().join(crate_dir).join("Cargo.toml");
    let text = std::fs::read_to_string(&path)
        .unwrap_or_else(|e| panic!("reading {}: {e}", path.display()));
    let value: toml::Table = text
        .parse()
        .unwrap_or_else(|e| panic!("parsing {}: {e}", path.display()));
    value
        .get("dependencies")
        .and_then(|d| d.as_table())
        .map(|t| t.keys().cloned().collect())
        .unwrap_or_default()
}

#[test]
fn each_crate_links_only_what_its_layer_may_use() {
    let rules: &[(&str, &[&str], &str)] = &[
        (
            "protocol",
            &[
                "tokio",
                "wgpu",
                "axum",
                "tokio-tungstenite",
                "lightwire-adapter",
                "lightwire-scene",
                "lightwire-solve",
                "lightwire-server",
            ],
            "every client shares the protocol crate",
        ),
        (
            "scene",
            &[
                "tokio",
                "wgpu",
                "axum",
                "tokio-tungstenite",
                "lightwire-adapter",
                "lightwire-solve",
                "lightwire-server",
            ],
            "scenes and the atlas are below the GPU, the solvers and the service",
        ),
        (
            "solve",
            &[
                "tokio",
                "axum",
                "tokio-tungstenite",
                "prometheus-client",
                "lightwire-server",
            ],
            "a solver runs without an async runtime or a network",
        ),
        (
            "client",
            &["lightwire-scene", "lightwire-solve", "lightwire-server"],
            "a game would link the solver",
        ),
        (
            "tests",
            &["lightwire-scene", "lightwire-solve", "lightwire-server"],
            "the process-level test kit is linked by client tests, which must not link the solver",
        ),
    ];
    for (dir, banned, why) in rules {
        let deps = dependencies(dir);
        for b in *banned {
            assert!(
                !deps.iter().any(|d| d == b),
                "{dir}/Cargo.toml depends on {b}: {why}"
            );
        }
    }
    // And the layers are there: a crate higher in the stack uses the one
    // below it.
    assert!(dependencies("solve").iter().any(|d| d == "lightwire-scene"));
    assert!(
        dependencies("server")
            .iter()
            .any(|d| d == "lightwire-solve")
    );
}

/// One source file of a crate: its path, its module path from the crate
/// root, and its code without comments, strings and inline test modules.
struct File {
    path: PathBuf,
    module: Vec<String>,
    code: String,
}

/// Every `.rs` file of a crate rooted at `src` (relative to the
/// workspace root), with its module path (`lib.rs` or `main.rs` is the
/// root; `a/mod.rs` and `a.rs` are `a`). A `bin/` folder holds crates of
/// their own and is left out, as is a `main.rs` beside a `lib.rs`.
fn crate_files(src: &str) -> Vec<File> {
    let src = root().join(src);
    let has_lib = src.join("lib.rs").is_file();
    let mut out = Vec::new();
    let mut stack = vec![src.clone()];
    while let Some(d) = stack.pop() {
        let entries =
            std::fs::read_dir(&d).unwrap_or_else(|e| panic!("reading {}: {e}", d.display()));
        for entry in entries {
            let path = entry.expect("directory entry").path();
            let relative = path.strip_prefix(&src).expect("under src").to_path_buf();
            if path.is_dir() {
                if relative != Path::new("bin") {
                    stack.push(path);
                }
                continue;
            }
            if path.extension().is_none_or(|x| x != "rs")
                || (has_lib && relative == Path::new("main.rs"))
            {
                continue;
            }
            let text = std::fs::read_to_string(&path)
                .unwrap_or_else(|e| panic!("reading {}: {e}", path.display()));
            let mut module: Vec<String> = relative
                .with_extension("")
                .components()
                .map(|c| c.as_os_str().to_string_lossy().into_owned())
                .collect();
            if matches!(
                module.last().map(String::as_str),
                Some("mod" | "lib" | "main")
            ) {
                module.pop();
            }
            out.push(File {
                path,
                module,
                code: without_tests(&strip(&text)),
            });
        }
    }
    assert!(!out.is_empty(), "no sources under {}", src.display());
    out
}

/// `text` with comments removed and string and char literals emptied, so
/// that what is left is code (newlines kept).
fn strip(text: &str) -> String {
    let b: Vec<char> = text.chars().collect();
    let mut out = String::with_capacity(text.len());
    let mut i = 0;
    while i < b.len() {
        let c = b[i];
        let next = b.get(i + 1).copied();
        if c == '/' && next == Some('/') {
            while i < b.len() && b[i] != '\n' {
                i += 1;
            }
        } else if c == '/' && next == Some('*') {
            let mut depth = 0;
            while i < b.len() {
                if b[i] == '/' && b.get(i + 1) == Some(&'*') {
                    depth += 1;
                    i += 2;
                } else if b[i] == '*' && b.get(i + 1) == Some(&'/') {
                    depth -= 1;
                    i += 2;
                    if depth == 0 {
                        break;
                    }
                } else {
                    if b[i] == '\n' {
                        out.push('\n');
                    }
                    i += 1;
                }
            }
        } else if c == 'r' && (next == Some('"') || next == Some('#')) && !ident_before(&b, i) {
            // A raw string: r"..." or r#"..."#.
            let mut j = i + 1;
            let mut hashes = 0;
            while b.get(j) == Some(&'#') {
                hashes += 1;
                j += 1;
            }
            if b.get(j) != Some(&'"') {
                out.push(c);
                i += 1;
                continue;
            }
            j += 1;
            loop {
                if j >= b.len() {
                    break;
                }
                if b[j] == '"' && (0..hashes).all(|k| b.get(j + 1 + k) == Some(&'#')) {
                    j += 1 + hashes;
                    break;
                }
                if b[j] == '\n' {
                    out.push('\n');
                }
                j += 1;
            }
            out.push_str("\"\"");
            i = j;
        } else if c == '"' {
            i += 1;
            while i < b.len() && b[i] != '"' {
                if b[i] == '\\' {
                    i += 1;
                } else if b[i] == '\n' {
                    out.push('\n');
                }
                i += 1;
            }
            out.push_str("\"\"");
            i += 1;
        } else if c == '\'' && next == Some('\\') {
            // An escaped char literal.
            i += 2;
            while i < b.len() && b[i] != '\'' {
                i += 1;
            }
            out.push_str("' '");
            i += 1;
        } else if c == '\'' && b.get(i + 2) == Some(&'\'') {
            out.push_str("' '");
            i += 3;
        } else {
            out.push(c);
            i += 1;
        }
    }
    out
}

fn ident_before(b: &[char], i: usize) -> bool {
    i > 0 && (b[i - 1].is_alphanumeric() || b[i - 1] == '_')
}

/// `code` without its `#[cfg(test)] mod NAME { ... }` blocks: what tests
/// import is not architecture.
fn without_tests(code: &str) -> String {
    let mut out = code.to_string();
    while let Some(at) = out.find("#[cfg(test)]") {
        let rest = &out[at + "#[cfg(test)]".len()..];
        let trimmed = rest.trim_start();
        let is_module = trimmed.starts_with("mod ") || trimmed.starts_with("pub mod ");
        let Some(open) = rest.find(['{', ';']).filter(|_| is_module) else {
            // An attribute on something else: drop the attribute only.
            out.replace_range(at..at + "#[cfg(test)]".len(), "");
            continue;
        };
        let start = at + "#[cfg(test)]".len() + open;
        let mut end = start + 1;
        if out.as_bytes()[start] == b'{' {
            let mut depth = 0;
            for (k, ch) in out[start..].char_indices() {
                match ch {
                    '{' => depth += 1,
                    '}' => {
                        depth -= 1;
                        if depth == 0 {
                            end = start + k + 1;
                            break;
                        }
                    }
                    _ => {}
                }
            }
        }
        out.replace_range(at..end, "");
    }
    out
}

/// The paths a `use` tree names, each as its segments (`a::{b, c::d as
/// e}` gives `a::b` and `a::c::d`; a glob ends in `*`).
fn expand(tree: &str) -> Vec<Vec<String>> {
    let tree: String = tree.split_whitespace().collect::<Vec<_>>().join(" ");
    let mut out = Vec::new();
    expand_into(&tree, &[], &mut out);
    out
}

fn expand_into(tree: &str, prefix: &[String], out: &mut Vec<Vec<String>>) {
    let tree = tree.trim().trim_start_matches("::");
    if tree.is_empty() {
        return;
    }
    if let Some(open) = tree.find('{') {
        let head: Vec<String> = segments(&tree[..open]);
        let close = tree.rfind('}').unwrap_or(tree.len());
        let mut base = prefix.to_vec();
        base.extend(head);
        for part in split_top(&tree[open + 1..close]) {
            if part.trim() == "self" {
                out.push(base.clone());
            } else {
                expand_into(&part, &base, out);
            }
        }
    } else {
        let path = tree.split(" as ").next().unwrap_or(tree);
        let mut full = prefix.to_vec();
        full.extend(segments(path));
        if full.last().is_some_and(|s| s == "self") {
            full.pop();
        }
        out.push(full);
    }
}

fn segments(path: &str) -> Vec<String> {
    path.split("::")
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(String::from)
        .collect()
}

/// `a, b::{c, d}, e` split at the commas outside braces.
fn split_top(list: &str) -> Vec<String> {
    let (mut parts, mut depth, mut current) = (Vec::new(), 0, String::new());
    for ch in list.chars() {
        match ch {
            '{' => depth += 1,
            '}' => depth -= 1,
            ',' if depth == 0 => {
                parts.push(std::mem::take(&mut current));
                continue;
            }
            _ => {}
        }
        current.push(ch);
    }
    parts.push(current);
    parts.into_iter().filter(|p| !p.trim().is_empty()).collect()
}

/// Every `use` declaration of `code` (its tree, without `use` and `;`).
fn use_trees(code: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut rest = code;
    while let Some(at) = find_word(rest, "use") {
        let after = &rest[at + 3..];
        let Some(end) = after.find(';') else { break };
        out.push(after[..end].to_string());
        rest = &after[end..];
    }
    out
}

/// `code` without its re-exports (`pub use`, `pub(crate) use`, ...): a
/// re-export hands a name on, as a crate's or a module's face, and is no
/// use of it by the file's own code.
fn without_reexports(code: &str) -> String {
    let mut out = String::with_capacity(code.len());
    let mut rest = code;
    while let Some(at) = find_word(rest, "pub") {
        let after = &rest[at + 3..];
        let visibility = if after.starts_with('(') {
            after.find(')').map_or(0, |k| k + 1)
        } else {
            0
        };
        let is_use = find_word(&after[visibility..], "use")
            .is_some_and(|k| after[visibility..visibility + k].trim().is_empty());
        match (is_use, after.find(';')) {
            (true, Some(end)) => {
                out.push_str(&rest[..at]);
                rest = &after[end + 1..];
            }
            _ => {
                out.push_str(&rest[..at + 3]);
                rest = after;
            }
        }
    }
    out.push_str(rest);
    out
}

/// Where the word `word` starts in `text` (not inside a longer name).
fn find_word(text: &str, word: &str) -> Option<usize> {
    let mut from = 0;
    while let Some(k) = text[from..].find(word) {
        let at = from + k;
        let before = text[..at].chars().next_back();
        let after = text[at + word.len()..].chars().next();
        let boundary = |c: Option<char>| !c.is_some_and(|c| c.is_alphanumeric() || c == '_');
        if boundary(before) && boundary(after) {
            return Some(at);
        }
        from = at + word.len();
    }
    None
}

/// Paths written in code: `crate::a::b`, `super::c`, `self::d`, and
/// `lightwire_x::...` (another crate).
fn code_paths(code: &str) -> Vec<Vec<String>> {
    let mut out = Vec::new();
    let chars: Vec<char> = code.chars().collect();
    let mut i = 0;
    while i < chars.len() {
        let starts = (chars[i].is_alphabetic() || chars[i] == '_')
            && (i == 0 || !(chars[i - 1].is_alphanumeric() || chars[i - 1] == '_'));
        if !starts {
            i += 1;
            continue;
        }
        let mut j = i;
        while j < chars.len() && (chars[j].is_alphanumeric() || chars[j] == '_' || chars[j] == ':')
        {
            j += 1;
        }
        let path: String = chars[i..j].iter().collect();
        let segs = segments(&path);
        if path.contains("::")
            && segs.first().is_some_and(|s| {
                matches!(s.as_str(), "crate" | "super" | "self") || s.starts_with("lightwire_")
            })
        {
            out.push(segs);
        }
        i = j.max(i + 1);
    }
    out
}

/// The files of one crate by module path, and where each import leads.
struct Crate {
    files: Vec<File>,
    by_module: BTreeMap<Vec<String>, usize>,
}

impl Crate {
    fn new(crate_dir: &str) -> Self {
        let files = crate_files(crate_dir);
        let by_module = files
            .iter()
            .enumerate()
            .map(|(k, f)| (f.module.clone(), k))
            .collect();
        Self { files, by_module }
    }

    /// Whether file `k` defines an item named `name`.
    fn defines(&self, k: usize, name: &str) -> bool {
        let code = &self.files[k].code;
        [
            "fn", "struct", "enum", "trait", "type", "const", "static", "mod", "union",
        ]
        .iter()
        .any(|kw| {
            let mut rest = code.as_str();
            while let Some(at) = find_word(rest, kw) {
                let after = rest[at + kw.len()..].trim_start();
                if after.starts_with(name)
                    && !after[name.len()..].starts_with(|c: char| c.is_alphanumeric() || c == '_')
                {
                    return true;
                }
                rest = &rest[at + kw.len()..];
            }
            false
        }) || code.contains(&format!("macro_rules! {name}"))
    }

    /// The file an absolute module path (`a::b::Item...`) leads to from
    /// the crate root: the deepest module file, then the file that defines
    /// the next name there, through re-exports.
    fn resolve(&self, path: &[String], depth: u32) -> Option<usize> {
        let mut module: Vec<String> = Vec::new();
        let mut k = *self.by_module.get(&module)?;
        let mut rest = path;
        while let Some((first, tail)) = rest.split_first() {
            let mut deeper = module.clone();
            deeper.push(first.clone());
            match self.by_module.get(&deeper) {
                Some(&d) => {
                    module = deeper;
                    k = d;
                    rest = tail;
                }
                None => break,
            }
        }
        let Some(name) = rest.first().filter(|n| n.as_str() != "*") else {
            return Some(k);
        };
        if self.defines(k, name) || depth > 8 {
            return Some(k);
        }
        // A re-export: `pub use x::name` or `pub use x::*` in that file.
        for tree in use_trees(&self.files[k].code) {
            for used in expand(&tree) {
                let last = used.last().map(String::as_str);
                if last == Some(name.as_str()) || last == Some("*") {
                    let mut target = used.clone();
                    if last == Some("*") {
                        target.pop();
                        target.push(name.clone());
                    }
                    if let Some(t) = self.absolute(k, &target) {
                        if let Some(f) = self.resolve(&t, depth + 1) {
                            if f != k {
                                return Some(f);
                            }
                        }
                    }
                }
            }
        }
        Some(k)
    }

    /// `path` as written in file `k` made absolute from the crate root, or
    /// `None` for another crate's path.
    fn absolute(&self, k: usize, path: &[String]) -> Option<Vec<String>> {
        let mut module = self.files[k].module.clone();
        let mut rest = path;
        match rest.first().map(String::as_str) {
            Some("crate") => {
                module.clear();
                rest = &rest[1..];
            }
            Some("self") => rest = &rest[1..],
            Some("super") => {
                while rest.first().is_some_and(|s| s == "super") {
                    module.pop();
                    rest = &rest[1..];
                }
            }
            Some(first) => {
                // Relative to the current module only if it names a child.
                let mut child = module.clone();
                child.push(first.to_string());
                self.by_module.get(&child)?;
            }
            None => return None,
        }
        module.extend(rest.iter().cloned());
        Some(module)
    }

    /// Every file each file imports (by index), with the path written.
    fn imports(&self) -> Vec<BTreeMap<usize, String>> {
        (0..self.files.len())
            .map(|k| {
                let code = without_reexports(&self.files[k].code);
                let mut paths: Vec<Vec<String>> =
                    use_trees(&code).iter().flat_map(|t| expand(t)).collect();
                paths.extend(code_paths(&code));
                let mut out = BTreeMap::new();
                for p in paths {
                    if let Some(t) = self.absolute(k, &p).and_then(|a| self.resolve(&a, 0)) {
                        // A file's submodules are parts of it: what they take
                        // from it (`super::`) is no import between files.
                        let ancestor = self.files[k].module.starts_with(&self.files[t].module);
                        if t != k && !ancestor {
                            out.entry(t).or_insert_with(|| p.join("::"));
                        }
                    }
                }
                out
            })
            .collect()
    }

    fn name(&self, k: usize) -> String {
        let path = &self.files[k].path;
        path.strip_prefix(root())
            .unwrap_or(path)
            .display()
            .to_string()
    }
}

/// The root folder of every crate of the workspace (each binary of its
/// own beside its package's library).
const CRATES: [&str; 8] = [
    "protocol/src",
    "gpu-adapter/src",
    "scene/src",
    "solve/src",
    "server/src",
    "server/src/bin/lightwire",
    "client/src",
    "tests/src",
];

#[test]
fn no_two_files_import_each_other_in_a_loop() {
    for dir in CRATES {
        let krate = Crate::new(dir);
        let imports = krate.imports();
        // Depth-first search; a back edge closes a loop.
        let n = krate.files.len();
        let mut state = vec![0u8; n];
        let mut stack: Vec<usize> = Vec::new();
        fn visit(
            k: usize,
            imports: &[BTreeMap<usize, String>],
            state: &mut [u8],
            stack: &mut Vec<usize>,
        ) -> Option<Vec<usize>> {
            state[k] = 1;
            stack.push(k);
            for &t in imports[k].keys() {
                if state[t] == 1 {
                    let from = stack.iter().position(|&s| s == t).unwrap_or(0);
                    let mut cycle = stack[from..].to_vec();
                    cycle.push(t);
                    return Some(cycle);
                }
                if state[t] == 0 {
                    if let Some(c) = visit(t, imports, state, stack) {
                        return Some(c);
                    }
                }
            }
            stack.pop();
            state[k] = 2;
            None
        }
        for k in 0..n {
            if state[k] == 0 {
                if let Some(cycle) = visit(k, &imports, &mut state, &mut stack) {
                    let described: Vec<String> = cycle
                        .windows(2)
                        .map(|w| {
                            format!(
                                "{} -> {} ({})",
                                krate.name(w[0]),
                                krate.name(w[1]),
                                imports[w[0]][&w[1]]
                            )
                        })
                        .collect();
                    panic!(
                        "files of {dir} import each other in a loop:\n{}",
                        described.join("\n")
                    );
                }
            }
        }
    }
}

/// Files of `dir` whose imports reach a file under one of `targets`
/// (paths relative to the crate's `src/`; its binaries left out), or another crate named in
/// `crates`.
fn reaching(dir: &str, from: &str, targets: &[&str], crates: &[&str]) -> Vec<String> {
    let krate = Crate::new(&format!("{dir}/src"));
    let imports = krate.imports();
    let src = root().join(dir).join("src");
    let mut found = BTreeSet::new();
    for (k, file) in krate.files.iter().enumerate() {
        let relative = file
            .path
            .strip_prefix(&src)
            .expect("under src")
            .to_string_lossy()
            .into_owned();
        if !relative.starts_with(from) {
            continue;
        }
        for (&t, written) in &imports[k] {
            let target = krate.files[t]
                .path
                .strip_prefix(&src)
                .expect("under src")
                .to_string_lossy()
                .into_owned();
            if targets.iter().any(|p| target.starts_with(p)) {
                found.insert(format!("{relative} imports {written} ({target})"));
            }
        }
        for path in use_trees(&file.code)
            .iter()
            .flat_map(|t| expand(t))
            .chain(code_paths(&file.code))
        {
            if path.first().is_some_and(|c| crates.contains(&c.as_str())) {
                found.insert(format!("{relative} imports {}", path.join("::")));
            }
        }
    }
    found.into_iter().collect()
}

#[test]
fn a_relay_never_builds_a_solver() {
    let hits = reaching(
        "server",
        "relay",
        &["service/runtime.rs", "service/live.rs", "bench"],
        &["lightwire_solve"],
    );
    assert!(
        hits.is_empty(),
        "the relay reaches for the solver:\n{}",
        hits.join("\n")
    );
}

#[test]
fn the_gpu_solvers_know_neither_the_reference_nor_the_path_tracer() {
    let hits = reaching(
        "solve",
        "gpu",
        &["reference", "pathtrace", "solver.rs"],
        &[],
    );
    assert!(
        hits.is_empty(),
        "solve/src/gpu imports the reference, the path tracer or the batch interface:\n{}",
        hits.join("\n")
    );
    for from in ["reference", "pathtrace"] {
        let hits = reaching("solve", from, &["gpu", "solver.rs"], &[]);
        assert!(
            hits.is_empty(),
            "solve/src/{from} imports the GPU solvers:\n{}",
            hits.join("\n")
        );
    }
}

#[test]
fn the_gpu_building_blocks_know_no_solver() {
    for file in [
        "gpu/binding.rs",
        "gpu/buffers.rs",
        "gpu/placement.rs",
        "gpu/hemicube.rs",
    ] {
        let hits = reaching(
            "solve",
            file,
            &[
                "gpu/progressive",
                "gpu/gather",
                "gpu/dynamic",
                "gpu/correct",
            ],
            &[],
        );
        assert!(
            hits.is_empty(),
            "{file} is a building block but reaches for a solver:\n{}",
            hits.join("\n")
        );
    }
}

/// The parser itself: a `use` tree with nesting, `self`, aliases and a
/// glob; and code with a comment, a string and a test module that name
/// modules it does not import.
#[test]
fn the_import_parser_reads_what_rust_reads() {
    let mut paths = expand("super::{a::{self, B as C}, d::*, e}");
    paths.sort();
    let written: Vec<String> = paths.iter().map(|p| p.join("::")).collect();
    assert_eq!(
        written,
        ["super::a", "super::a::B", "super::d::*", "super::e"]
    );

    let code = strip(
        "use crate::x::Y; // use crate::z::W;\nlet s = \"crate::q::R\"; let c = '\"';\n/* crate::p::Q */ crate::v::f();\n#[cfg(test)]\nmod tests { use crate::t::T; }\n",
    );
    let code = without_tests(&code);
    let trees = use_trees(&code);
    assert_eq!(trees.len(), 1, "{code}");
    let mut found: Vec<String> = code_paths(&code).iter().map(|p| p.join("::")).collect();
    found.sort();
    assert_eq!(found, ["crate::v::f", "crate::x::Y"], "{code}");

    let face =
        without_reexports("pub use a::B;\npub(crate) use c::{D, E};\npub fn f() {}\nuse g::H;");
    assert_eq!(use_trees(&face), [" g::H"], "{face}");
}

#!/usr/bin/env python3
"""Builds the `config_parse` seed corpus and dictionary: the documented example
(systemd/glintd.toml), the TOML snippets written in the daemon's tests, and one seed per key
of every section (read from the configuration structs' sources), so that mutations start
from every key and the dictionary offers every section and key name.

    python3 daemon/fuzz/seed.py && cd daemon/fuzz
    RUSTC_BOOTSTRAP=1 cargo fuzz run config_parse corpus/config_parse -- -dict=corpus/config.dict
"""
import glob
import os
import re

here = os.path.dirname(os.path.abspath(__file__))
root = os.path.join(here, "..", "..")
out = os.path.join(here, "corpus", "config_parse")
os.makedirs(out, exist_ok=True)
seeds = {"example.toml": open(os.path.join(root, "systemd", "glintd.toml")).read()}

# String literals holding a section header in the daemon's tests and the parser's own tests;
# a `format!` placeholder becomes a plausible value.
sources = glob.glob(os.path.join(root, "daemon", "tests", "*.rs"))
sources.append(os.path.join(root, "daemon", "src", "config.rs"))
for path in sorted(sources):
    text = open(path).read()
    for i, literal in enumerate(re.findall(r'"((?:[^"\\]|\\.)*)"', text, re.S)):
        if not re.search(r"\[[a-z_.]+\]\\n", literal):
            continue
        s = re.sub(r"\\\n\s*", "", literal)
        s = s.replace("\\n", "\n").replace('\\"', '"').replace("\\\\", "\\")
        ports = iter(range(2368, 2468))
        s = re.sub(r"\{[a-z_.]*\}", lambda _: str(next(ports)), s)
        s = s.replace("{{", "{").replace("}}", "}")
        seeds[f"{os.path.basename(path)}.{i}.toml"] = s

# The configuration structs: field name → type, by struct.
structs = {}
for path in ["core/src/config.rs", "core/src/backend/config.rs", "core/src/localiser.rs",
             "daemon/src/config.rs"]:
    text = open(os.path.join(root, path)).read()
    for name, body in re.findall(r"pub struct (\w+) \{\n(.*?)\n\}", text, re.S):
        structs[name] = re.findall(r"^\s*pub (\w+): ([^\n]+),$", body, re.M)


def value(ty):
    ty = ty.strip()
    if ty.startswith("Option<"):
        return value(ty[7:-1])
    if ty.startswith("["):
        n = int(ty.rsplit(";", 1)[1].strip(" ]"))
        return "[" + ", ".join([value(ty[1:].split(";")[0])] * n) + "]"
    if ty in ("f64", "f32"):
        return "0.5"
    if ty in ("usize", "u64", "u32", "u16", "u8", "i32", "i64"):
        return "3"
    if ty == "bool":
        return "true"
    if ty == "IpAddr" or ty == "Ipv4Addr":
        return '"127.0.0.1"'
    if ty == "SiteMapMode":
        return '"mapping"'
    return '"x"'


keys, sections = set(), set()


def walk(struct, section):
    for field, ty in structs.get(struct, []):
        if ty in structs:
            sections.add(f"{section}.{field}".lstrip("."))
            walk(ty, f"{section}.{field}")
        else:
            keys.add(field)
            s = section.lstrip(".")
            seeds[f"key.{s}.{field}.toml"] = f"[{s}]\n{field} = {value(ty)}\n"


walk("DaemonConfig", "")
for name, text in seeds.items():
    open(os.path.join(out, name), "w").write(text)
with open(os.path.join(here, "corpus", "config.dict"), "w") as d:
    for s in sorted(sections):
        d.write(f'"[{s}]\\x0a"\n')
    for k in sorted(keys):
        d.write(f'"{k} = "\n')
    for t in ["true", "false", "nan", "inf", "-inf", "1e308", "0x", "0o", "0b", '"""', "'''",
              "[[", "]]", "{", "}", "= [", ", ", "\\x0a", "#", "1979-05-27T07:32:00Z"]:
        d.write('"' + t.replace("\\x0a", "\\x0a").replace('"', '\\"') + '"\n')
print(f"{len(seeds)} seeds, {len(sections)} sections and {len(keys)} keys in the dictionary")

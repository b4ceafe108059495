"""The docs cannot drift from the code: recipes, shipped models, config keys, the package layout
and every command the README and docs/ show are checked against what is there.

Each check is a function returning its problems (an empty list: none), so that the tests of the
tests below can show each one failing when a recipe, a shipped model or a config key is added
without its line. Fast: no LIGGGHTS, no training, no checkpoint is read.
"""

from __future__ import annotations

import argparse
import importlib
import re
import shlex
from collections.abc import Callable
from pathlib import Path

import hydra
import pytest
from hydra import initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from omegaconf import DictConfig, OmegaConf

from granular_pyg.config import CONF_DIR, compose
from granular_pyg.pretrained import PRETRAINED
from granular_pyg.pretrained.recipes import RECIPES

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "granular_pyg"
README = ROOT / "README.md"
ARCHITECTURE = ROOT / "docs" / "architecture.md"
RESULTS = ROOT / "docs" / "results.md"
DOCS = [README, *sorted((ROOT / "docs").glob("*.md"))]
MAX_RESULTS_BYTES = 25 * 1024
MAX_README_CHARS = 12_000


def _recipes() -> list[str]:
    return sorted(p.stem for p in (CONF_DIR / "experiment").glob("*.yaml"))


def _section(text: str, heading: str) -> str:
    """The text of the Markdown section ``heading`` (up to the next heading of its level)."""
    level = heading.split(" ")[0]
    start = text.index(heading + "\n")
    after = text[start + len(heading) + 1 :]
    end = re.search(rf"(?m)^{level} ", after)
    return after[: end.start()] if end else after


# -- recipes and shipped models ----------------------------------------------------------------


def recipe_problems(recipes: list[str], docs: dict[str, str]) -> list[str]:
    """Each recipe of ``conf/experiment`` named (as `` `name` ``) in each doc of ``docs``."""
    return [
        f"{doc}: recipe {name!r} (conf/experiment/{name}.yaml) is not named"
        for doc, text in docs.items()
        for name in recipes
        if f"`{name}`" not in text
    ]


def pretrained_problems(
    pretrained: dict[str, str],
    recipes: dict[str, str],
    experiments: list[str],
    readme: str,
    results: str,
) -> list[str]:
    """Each shipped model has its recipe recorded (an existing one), is named in the README, and
    has a row in results.md's pretrained table that names its recipe."""
    problems = []
    table = _section(results, "## Pretrained models")
    for name in sorted(pretrained):
        recipe = recipes.get(name)
        if recipe is None:
            problems.append(f"pretrained:{name}: no recipe in granular_pyg/pretrained/recipes.py")
        elif recipe not in experiments:
            problems.append(f"pretrained:{name}: recipe {recipe!r} is not in conf/experiment")
        if f"pretrained:{name}" not in readme:
            problems.append(f"README: pretrained:{name} is not named")
        row = next((r for r in table.splitlines() if r.startswith(f"| `pretrained:{name}`")), "")
        if not row:
            problems.append(f"results.md, pretrained models: no row for pretrained:{name}")
        elif recipe and f"`{recipe}`" not in row:
            problems.append(f"results.md: pretrained:{name}'s row names no `{recipe}`")
    extra = sorted(set(recipes) - set(pretrained))
    problems += [f"recipes.py: {name!r} is no shipped model" for name in extra]
    return problems


# -- config keys ------------------------------------------------------------------------------


def documented_keys(architecture: str) -> dict[str, list[str]]:
    """The table of architecture.md's Configs section: ``{scope: [key, ...]}``, a scope being a
    config name (``train``) or a section of one (``train.model``)."""
    rows = {}
    for line in _section(architecture, "## Configs").splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 2 and re.fullmatch(r"`[a-z_.]+`", cells[0]):
            rows[cells[0].strip("`")] = re.findall(r"`([A-Za-z_][\w]*)`", cells[1])
    return rows


def _config_keys(cfg: DictConfig, scope: str) -> set[str]:
    node = cfg if "." not in scope else OmegaConf.select(cfg, scope.split(".", 1)[1])
    return {k for k in node if k != "hydra" and not str(k).startswith("_")}


def config_key_problems(
    documented: dict[str, list[str]], composed: Callable[[str], DictConfig]
) -> list[str]:
    """Each documented key exists in its composed config, and each key of a documented config or
    section is documented."""
    problems = []
    for scope, keys in documented.items():
        actual = _config_keys(composed(scope.split(".")[0]), scope)
        gone = [k for k in keys if k not in actual]
        new = sorted(actual - set(keys))
        problems += [f"{scope}: documented key {k!r} is not in the config" for k in gone]
        problems += [f"{scope}: key {k!r} is not in architecture.md's table" for k in new]
    return problems


# -- the layout -------------------------------------------------------------------------------


_PATH = re.compile(r"[\w.\-]+(/[\w.\-]+)*/?")


def layout_paths(architecture: str) -> list[str]:
    """The paths the Layout section's code block names: one or more path fields at the start
    of a line (fields are separated by two or more spaces), nested by indentation under the
    folders (``name/``) above them."""
    block = re.search(r"```\n(.*?)```", _section(architecture, "## Layout"), re.S).group(1)
    paths, parents = [], []  # parents: (indent, folder)
    for line in block.splitlines():
        indent = len(line) - len(line.lstrip(" "))
        fields = re.split(r" {2,}", line.strip())
        names = []
        for field in fields:
            if not _PATH.fullmatch(field) or not re.search(r"/|\.\w+$|^Makefile$", field):
                break
            names.append(field)
        if not names:
            continue
        while parents and parents[-1][0] >= indent:
            parents.pop()
        prefix = parents[-1][1] if parents else ""
        for name in names:
            paths.append(prefix + name)
        if len(names) == 1 and names[0].endswith("/"):
            parents.append((indent, prefix + names[0]))
    return paths


def layout_problems(paths: list[str], root: Path) -> list[str]:
    """Each named path exists; a package folder whose modules the layout lists one by one lists
    all of them; every top-level module and sub-package of ``granular_pyg/`` is named."""
    problems = [f"layout: {p} does not exist" for p in paths if not (root / p).exists()]
    named = set(paths)
    folders = {str(Path(p).parent) + "/" for p in paths if p.endswith(".py")}
    for folder in sorted(folders | {"granular_pyg/"}):
        for module in sorted((root / folder).glob("*.py")):
            rel = module.relative_to(root).as_posix()
            if not module.name.startswith("__") and rel not in named:
                problems.append(f"layout: {rel} is not listed beside the rest of {folder}")
    for sub in sorted((root / "granular_pyg").iterdir()):
        rel = sub.relative_to(root).as_posix() + "/"
        if (sub / "__init__.py").is_file() and rel not in named:
            problems.append(f"layout: the package folder {rel} is not listed")
    return problems


# -- commands ---------------------------------------------------------------------------------


def commands(text: str) -> list[str]:
    """Every ``python -m granular_pyg.<command> ...`` of a Markdown text: the lines of its code
    blocks (``\\`` continuations joined, comments dropped, a ``for x in a b`` loop's ``$x`` taken
    as ``a``, a config copied with ``cp conf/<group>/a.yaml conf/<group>/b.yaml`` composed as
    ``a``) and its inline code spans."""
    found = []
    for block in re.findall(r"```\w*\n(.*?)```", text, re.S):
        loops, copies = {}, {}
        for line in block.replace("\\\n", " ").splitlines():
            line = line.strip()
            loops |= {f"${name}": first for name, first in re.findall(r"for (\w+) in (\S+)", line)}
            copied = re.findall(r"cp conf/(\S+)/(\w+)\.yaml conf/\1/(\w+)\.yaml", line)
            for group, made, copy in copied:
                copies[f"{group}={copy}"] = f"{group}={made}"
            for old, new in (loops | copies).items():
                line = line.replace(old, new)
            if line.startswith("python -m granular_pyg."):
                found.append(line)
            elif "do python -m granular_pyg." in line or "; python -m granular_pyg." in line:
                found.append("python -m granular_pyg." + line.split(" -m granular_pyg.", 1)[1])
    prose = re.sub(r"```.*?```", "", text, flags=re.S)
    for span in re.findall(r"(?<!`)`([^`]+)`(?!`)", prose):
        span = " ".join(span.split())
        if span.startswith("python -m granular_pyg."):
            found.append(span)
    return found


def _placeholders_filled(text: str) -> str:
    """``<a|b>`` -> ``a`` (the first choice), any other ``<...>`` -> ``X``."""
    text = re.sub(r"<([^<>|]*)\|[^<>]*>", r"\1", text)
    return re.sub(r"<[^<>]*>", "X", text)


def _split(command: str) -> tuple[str, list[str]]:
    words = shlex.split(_placeholders_filled(command.split(";")[0]), comments=True)
    return words[2], [w for w in words[3:] if w != "..."]


def _module_file(module: str) -> Path | None:
    base = ROOT / module.replace(".", "/")
    for path in (base.with_suffix(".py"), base / "__main__.py"):
        if path.is_file():
            return path
    return None


class _Parsed(Exception):
    """Raised by the patched ``parse_args`` once an argparse command line has parsed."""


def _hydra_problem(config_name: str, args: list[str]) -> str | None:
    sweep = "-m" in args or "--multirun" in args
    overrides = [a for a in args if not a.startswith("-") and a != "X"]  # X: `<overrides>`
    if sweep:  # the first point of each sweep
        overrides = [o if "[" in o or "," not in o else o.split(",")[0] for o in overrides]
    GlobalHydra.instance().clear()
    try:
        with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
            hydra.compose(config_name=config_name, overrides=overrides, return_hydra_config=True)
    except Exception as exc:  # every failure is the command's problem
        return f"{type(exc).__name__}: {exc}".splitlines()[0]
    finally:
        GlobalHydra.instance().clear()
    return None


def _argparse_problem(module: str, args: list[str], monkeypatch) -> str | None:
    real = argparse.ArgumentParser.parse_args

    def parse_then_stop(self, argv=None, namespace=None):
        real(self, argv, namespace)
        raise _Parsed

    monkeypatch.setattr(argparse.ArgumentParser, "parse_args", parse_then_stop)
    try:
        importlib.import_module(module).main(args)
    except _Parsed:
        return None
    except SystemExit as exc:
        return f"argparse refused it (exit {exc.code})"
    finally:
        monkeypatch.setattr(argparse.ArgumentParser, "parse_args", real)
    return "main() returned without parsing its arguments"


def command_problem(command: str, monkeypatch) -> str | None:
    """Why ``command`` does not parse: Hydra commands compose their config with the overrides,
    argparse commands parse their arguments (nothing runs); None when it parses."""
    module, args = _split(command)
    if module.endswith(".X"):  # `python -m granular_pyg.<command>`: a pattern, not a command
        return None
    path = _module_file(module)
    if path is None:
        return f"{module}: no such module"
    source = path.read_text()
    hydra_app = re.search(r"@command\(\"(\w+)\"\)", source)
    if hydra_app:
        return _hydra_problem(hydra_app.group(1), args)
    if "argparse" in source:
        return _argparse_problem(module, args, monkeypatch) if args else None
    return f"{module}: neither a Hydra command nor an argparse one"


# -- the tests --------------------------------------------------------------------------------


def _composed(name: str) -> DictConfig:
    return compose(name, [])


def test_results_and_readme_are_short():
    assert RESULTS.stat().st_size <= MAX_RESULTS_BYTES
    assert len(README.read_text()) <= MAX_README_CHARS


def test_results_keep_the_sections_the_readme_links_to():
    headings = re.findall(r"(?m)^#+ (.+)$", RESULTS.read_text())
    anchors = {re.sub(r"[^\w\- ]", "", h.lower()).replace(" ", "-") for h in headings}
    for doc in DOCS:
        for anchor in re.findall(r"results\.md#([\w\-]+)", doc.read_text()):
            assert anchor in anchors, f"{doc.name}: results.md#{anchor}"


def test_every_recipe_is_named_in_the_readme_and_the_architecture():
    docs = {"README.md": README.read_text(), "architecture.md": ARCHITECTURE.read_text()}
    assert recipe_problems(_recipes(), docs) == []


def test_every_shipped_model_has_its_recipe_and_its_lines():
    problems = pretrained_problems(
        PRETRAINED, RECIPES, _recipes(), README.read_text(), RESULTS.read_text()
    )
    assert problems == []


def test_every_config_key_in_the_configs_table_exists_and_every_key_is_there():
    documented = documented_keys(ARCHITECTURE.read_text())
    primaries = sorted(p.stem for p in CONF_DIR.glob("*.yaml"))
    assert sorted({s.split(".")[0] for s in documented}) == primaries
    assert config_key_problems(documented, _composed) == []


def test_every_file_in_the_layout_exists_and_no_module_is_left_out():
    paths = layout_paths(ARCHITECTURE.read_text())
    assert "granular_pyg/dem/" in paths or "granular_pyg/dem_import/" in paths
    assert layout_problems(paths, ROOT) == []


def test_the_docs_name_every_bench_suite():
    suites = sorted(p.stem for p in (CONF_DIR / "suite").glob("*.yaml"))
    for doc in (README, ARCHITECTURE):
        text = doc.read_text()
        assert [s for s in suites if f"`{s}`" not in text] == [], doc.name


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: p.name)
def test_every_command_in_the_docs_parses(doc, monkeypatch):
    found = commands(doc.read_text())
    problems = {c: command_problem(c, monkeypatch) for c in found}
    assert {c: p for c, p in problems.items() if p} == {}


def command_style_problems(readme: str, package: Path) -> list[str]:
    """The README's Configs section names which commands are Hydra and which take ``--flags``;
    each named one is of its style, and every argparse entry point is named."""
    text = " ".join(_section(readme, "## Configs").split())
    hydra_part = text[text.index("Hydra:") : text.index("takes `key=value`")]
    flags_part = text[text.index("The tools") : text.index("take `--flags`")]
    hydra_named = re.findall(r"`(\w[\w.]*)`", hydra_part)
    flags_named = re.findall(r"`(\w[\w.]*)`", flags_part)
    problems = []
    for name in hydra_named + flags_named:
        path = _module_file(f"granular_pyg.{name}")
        source = path.read_text() if path else ""
        is_hydra = "@command(" in source
        if path is None or is_hydra != (name in hydra_named):
            style = "Hydra" if name in hydra_named else "--flags"
            problems.append(f"README: `{name}` is listed as a {style} command; it is not one")
    for path in sorted(package.rglob("*.py")):
        source = path.read_text()
        if "argparse" in source and '__name__ == "__main__"' in source:
            name = ".".join(path.relative_to(package).with_suffix("").parts)
            if name not in flags_named:
                problems.append(f"README: the --flags command `{name}` is not listed")
    return problems


def test_the_readme_names_each_commands_style():
    assert command_style_problems(README.read_text(), PACKAGE) == []


def test_the_readme_and_the_architecture_show_commands():
    assert len(commands(README.read_text())) >= 10
    assert len(commands(ARCHITECTURE.read_text())) >= 10


def test_config_comments_name_each_shipped_models_own_recipe():
    for path in sorted(CONF_DIR.rglob("*.yaml")):
        for line in path.read_text().splitlines():
            value, _, comment = line.partition("#")  # a value pretrained:<name>, its comment
            shipped = re.search(r"pretrained:(\w+)", value)
            recipe = re.search(r"\+experiment=(\w+)", comment)
            if shipped and recipe and shipped.group(1) in RECIPES:
                assert recipe.group(1) == RECIPES[shipped.group(1)], f"{path.name}: {line}"


# -- the tests of the tests: each check fails when a line is missing ---------------------------


def test_a_recipe_added_without_its_doc_line_fails():
    docs = {"README.md": README.read_text(), "architecture.md": ARCHITECTURE.read_text()}
    problems = recipe_problems([*_recipes(), "new_recipe"], docs)
    assert problems == [
        "README.md: recipe 'new_recipe' (conf/experiment/new_recipe.yaml) is not named",
        "architecture.md: recipe 'new_recipe' (conf/experiment/new_recipe.yaml) is not named",
    ]


def test_a_shipped_model_added_without_its_recipe_and_lines_fails():
    pretrained = PRETRAINED | {"new_model": "new_model_v3.ckpt"}
    problems = pretrained_problems(
        pretrained, RECIPES, _recipes(), README.read_text(), RESULTS.read_text()
    )
    assert problems == [
        "pretrained:new_model: no recipe in granular_pyg/pretrained/recipes.py",
        "README: pretrained:new_model is not named",
        "results.md, pretrained models: no row for pretrained:new_model",
    ]
    recipes = RECIPES | {"hopper": "no_such_recipe"}
    problems = pretrained_problems(
        PRETRAINED, recipes, _recipes(), README.read_text(), RESULTS.read_text()
    )
    assert "pretrained:hopper: recipe 'no_such_recipe' is not in conf/experiment" in problems


def test_a_config_key_added_without_its_line_fails():
    def with_a_new_key(name: str) -> DictConfig:
        cfg = _composed(name)
        OmegaConf.set_struct(cfg, False)
        if name == "train":
            cfg.model.new_key = 1
            cfg.new_top_key = 2
        return cfg

    documented = documented_keys(ARCHITECTURE.read_text())
    before = set(config_key_problems(documented, _composed))  # whatever drift there is today
    problems = set(config_key_problems(documented, with_a_new_key)) - before
    assert sorted(problems) == [
        "train.model: key 'new_key' is not in architecture.md's table",
        "train: key 'new_top_key' is not in architecture.md's table",
    ]
    rollout = {"rollout": [*documented["rollout"], "gone_key"]}
    assert "rollout: documented key 'gone_key' is not in the config" in config_key_problems(
        rollout, _composed
    )


def test_a_layout_with_a_missing_file_or_a_module_left_out_fails(tmp_path):
    pkg = tmp_path / "granular_pyg"
    (pkg / "dem").mkdir(parents=True)
    for name in ("__init__.py", "a.py", "dem/__init__.py", "dem/x.py", "dem/y.py"):
        (pkg / name).write_text("")
    doc = (
        "## Layout\n\n```\ngranular_pyg/\n  a.py   one\n  dem/   two\n    x.py  z.py    three\n```"
    )
    paths = layout_paths(doc)
    assert paths == [
        "granular_pyg/",
        "granular_pyg/a.py",
        "granular_pyg/dem/",
        "granular_pyg/dem/x.py",
        "granular_pyg/dem/z.py",
    ]
    assert layout_problems(paths, tmp_path) == [
        "layout: granular_pyg/dem/z.py does not exist",
        "layout: granular_pyg/dem/y.py is not listed beside the rest of granular_pyg/dem/",
    ]


def test_a_command_style_the_readme_does_not_state_fails(tmp_path):
    readme = README.read_text().replace("`data.combine`, ", "")
    assert command_style_problems(readme, PACKAGE) == [
        "README: the --flags command `data.combine` is not listed"
    ]
    readme = README.read_text().replace("`bench` takes", "`bench`, `demo` takes")
    assert "README: `demo` is listed as a Hydra command; it is not one" in command_style_problems(
        readme, PACKAGE
    )


def test_a_command_that_does_not_parse_fails(monkeypatch):
    text = (
        "```bash\npython -m granular_pyg.train +experiment=no_such_recipe\n```\n"
        "and `python -m granular_pyg.rollout ckpt=<run>/last.ckpt no_such_key=1` and\n"
        "`python -m granular_pyg.data.combine data/x --no-such-flag`, "
        "`python -m granular_pyg.evaluate ckpt=pretrained:hopper wall_guard=<true|false>`"
    )
    found = commands(text)
    assert len(found) == 4
    problems = [command_problem(c, monkeypatch) for c in found]
    assert all(problems[:3]), problems
    assert problems[3] is None

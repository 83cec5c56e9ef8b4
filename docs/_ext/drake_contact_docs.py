"""Sphinx directives that write the reference pages from the code, so they
cannot drift from it, and that show the reference results (the committed
snapshots of ``docs/results/``).

- ``scenario-fields SECTION``: every field of a scenario section (or, with
  no argument, the top-level fields), its type, its default and the comment
  that documents it in the dataclass. At the end of the build, a section of
  :class:`drake_contact.Scenario` that no page lists is a warning.
- ``station-signals SCENARIO``: the station's exported signals for a bundled
  scenario, built here: size, meaning, log keys.
- ``measured-signals``: :data:`drake_contact.measured.MEASUREMENTS`.
- ``scores``: the metrics registered with
  :func:`drake_contact.scoring.metrics.register_metric`.
- ``reproduction-status``: the README's status paragraph, from the
  reproduction's snapshot.
- ``reference-results``: the snapshots, what each runs and how long its
  refresh took.
- ``generated STUDY``: a part of a study's Markdown in its reference-results
  snapshot, ``docs/results/STUDY/`` (committed; made by ``python
  docs/results.py``), stamped with its commit, date and refresh time. A
  study with no snapshot is a build warning (an error in the test suite's
  build) and a note naming the command that makes it.
"""

import ast
import dataclasses
import fnmatch
import importlib
import inspect
import json
import os
import pkgutil
import re
import textwrap
import typing
from pathlib import Path

from docutils import nodes
from docutils.parsers.rst import directives
from docutils.statemachine import StringList
from sphinx.util import logging
from sphinx.util.docutils import SphinxDirective

#: The committed snapshots of the reference results (``docs/results.py``).
RESULTS = Path(__file__).resolve().parents[1] / "results"
logger = logging.getLogger(__name__)
_SECTIONS_LISTED = "drake_contact_scenario_sections"


def _field_comments(cls) -> dict:
    """The comment lines right above each field of a dataclass; a field with
    none shares the comment of the field before it (a group of fields under
    one comment)."""
    lines, _ = inspect.getsourcelines(cls)
    tree = ast.parse(textwrap.dedent("".join(lines)))
    comments, previous = {}, ""
    for statement in tree.body[0].body:
        if not (isinstance(statement, ast.AnnAssign) and isinstance(statement.target, ast.Name)):
            continue
        block, row = [], statement.lineno - 2
        while row >= 0 and lines[row].strip().startswith("#"):
            block.insert(0, lines[row].strip().lstrip("#").strip())
            row -= 1
        text = " ".join(block) if block else previous
        comments[statement.target.id] = previous = text
    return comments


def _type_name(annotation) -> str:
    if isinstance(annotation, type):
        return annotation.__name__
    return str(annotation).replace("typing.", "")


def _default(field):
    if field.default is not dataclasses.MISSING:
        return field.default
    if field.default_factory is not dataclasses.MISSING:
        return field.default_factory()
    return None


def _cell(text) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def _code(value) -> str:
    text = repr(value) if isinstance(value, str) else f"{value}"
    if len(text) > 60:
        text = text[:57] + "..."
    return f"`{text}`" if text else ""


def _section(hint):
    """The dataclass a field of this type holds (itself, or a list's
    element), or None for a plain value."""
    element = typing.get_args(hint)[0] if typing.get_origin(hint) is list else hint
    return element if dataclasses.is_dataclass(element) else None


def scenario_rows(cls, prefix: str, *, recurse: bool = True):
    """(dotted path, type, default, comment) for every field under ``cls``:
    a section's row has the default "(section)" and is followed by its
    fields (unless ``recurse`` is false); a list of dataclasses is described
    by its element's fields under ``prefix[i]``."""
    hints = typing.get_type_hints(cls)
    comments = _field_comments(cls)
    for field in dataclasses.fields(cls):
        path = f"{prefix}.{field.name}" if prefix else field.name
        hint = hints[field.name]
        section = _section(hint)
        if section is None:
            yield path, _type_name(hint), _code(_default(field)), comments[field.name]
            continue
        listed = section is not hint
        kind = f"list of {section.__name__}" if listed else section.__name__
        yield path, kind, "(section)", comments[field.name] or section.__doc__
        if recurse:
            yield from scenario_rows(section, f"{path}[i]" if listed else path)


def _table(header: list, rows) -> str:
    """A Markdown table; a ``|`` inside a cell is escaped."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(_cell(cell) for cell in row) + " |" for row in rows]
    return "\n".join(lines)


class _MarkdownDirective(SphinxDirective):
    """A directive whose content is Markdown it writes."""

    def markdown(self) -> str:
        raise NotImplementedError

    def run(self):
        container = nodes.container()
        self.state.nested_parse(StringList(self.markdown().splitlines()), self.content_offset,
                                container)
        return container.children


class ScenarioFields(_MarkdownDirective):
    optional_arguments = 1

    def markdown(self):
        from drake_contact.scenario import Scenario

        intro, rows = "", scenario_rows(Scenario, "", recurse=False)
        if self.arguments:
            name = self.arguments[0]
            hint = typing.get_type_hints(Scenario).get(name)
            section = _section(hint) if hint is not None else None
            if section is None:
                raise self.error(f"Scenario has no section {name!r}")
            listed = getattr(self.env, _SECTIONS_LISTED, set())
            setattr(self.env, _SECTIONS_LISTED, listed | {name})
            intro = f"{(section.__doc__ or '').strip()}\n\n"
            rows = scenario_rows(section, f"{name}[i]" if section is not hint else name)
        return intro + _table(["field", "type", "default", "meaning"], (
            (f"`{path}`", kind, default, doc) for path, kind, default, doc in rows
            if default != "(section)"))


class StationSignals(_MarkdownDirective):
    required_arguments = 1

    def markdown(self):
        import drake_contact as dc

        station = dc.MakeContactDiagram(dc.load_scenario(self.arguments[0]))
        return _table(["signal", "size", "meaning", "logged as"], (
            (f"`{name}`", signal.size or "-", signal.meaning,
             ", ".join(f"`{key}`" for key in signal.log_as) or "not logged")
            for name, signal in station.signals.items()))


class MeasuredSignalsTable(_MarkdownDirective):
    def markdown(self):
        from drake_contact.measured import MEASUREMENTS

        return _table(["signal", "role", "size", "meaning", "station output"], (
            (f"`{name}`", f"`{m.role}`", m.size, m.meaning, "yes" if m.station else "no")
            for name, m in MEASUREMENTS.items()))


class ScoresTable(_MarkdownDirective):
    def markdown(self):
        from drake_contact.scoring.metrics import SCORES

        return _table(["benchmark column", "metrics.json key", "scale", "leaderboard column"], (
            (f"`{score.column}`", f"`{score.key}`", f"{score.scale:g}",
             f"{score.header} ({' / '.join(score.show)})" if score.show else "CSV only")
            for score in SCORES))


class ThesisClaims(_MarkdownDirective):
    """The thesis's claims (``drake_contact.app.claims.CLAIMS``): their lines,
    words, runs and criteria from the code; each seed's values and the
    verdict from the reference reproduction's snapshot (its ``claims.csv``)."""

    def markdown(self):
        import csv

        from drake_contact.app.claims import CLAIMS, TABLE_COLUMNS, claim_cells

        source = RESULTS / "reproduce" / "claims.csv"
        scored = {}
        if source.exists():
            self.env.note_dependency(str(source))
            with open(source, newline="") as stream:
                for line in csv.DictReader(stream):
                    values = line["values"] or "not run"
                    mark = {"True": " (holds)", "False": " (fails)"}.get(line["holds"], "")
                    entry = scored.setdefault(line["id"], {"verdict": line["verdict"]})
                    entry[f"seed {line['seed']}"] = values + mark
        seeds = sorted({key for entry in scored.values() for key in entry if key != "verdict"})
        header = TABLE_COLUMNS + seeds + (["verdict"] if scored else [])
        rows = []
        for claim in CLAIMS:
            entry = scored.get(claim.id, {})
            rows.append(claim_cells(claim) + [entry.get(seed, "not run") for seed in seeds]
                        + ([entry.get("verdict", "not run")] if scored else []))
        if not scored:
            logger.warning("the reproduction's snapshot (docs/results/reproduce/claims.csv) "
                           "is missing: make it with python docs/results.py --study reproduce",
                           location=self.get_location())
        return _table(header, rows)


class PolicySpaces(_MarkdownDirective):
    """The policy's observation and action, from policy_spaces."""

    def markdown(self):
        from drake_contact.control import policy_spaces as ps

        observation = _table(["index", "observation", "scale", "signal"], (
            (i, f"`{name}`", f"{scale:g}", meaning)
            for i, (name, scale, meaning) in enumerate(ps.OBSERVATION_FIELDS)))
        effects = {
            "force_residual": f"adds {ps.RESIDUAL_N:g} a N to the hybrid law's force command "
                              "along x",
            "force_gain_scale": f"K_fp times {ps.GAIN_SCALE_BASE:g}^a",
            "integral_gain_scale": f"K_fi times {ps.GAIN_SCALE_BASE:g}^a",
            "damping_x": f"D_x + {ps.DAMPING_N_S_PER_M:g} a N s/m, at least 0"}
        if set(effects) != set(ps.ACTION.names()):
            raise self.error(f"policy-spaces: document every action field: {ps.ACTION.names()}")
        action = _table(["index", "action a", "effect in contact"], (
            (i, f"`{name}`", effects[name]) for i, name in enumerate(ps.ACTION.names())))
        return (f"**Observation** ({ps.OBSERVATION.size}, each signal over its scale, clipped "
                f"to ±{ps.OBSERVATION_BOUND:g}):\n\n{observation}\n\n**Action** "
                f"({ps.ACTION.size}, each in [{ps.ACTION_LOW:g}, {ps.ACTION_HIGH:g}], clipped "
                f"there):\n\n{action}")


def _study_markdown(text: str, folder: str, drop: set, only: set) -> str:
    """A study's Markdown as part of a page: its title and the dropped
    sections removed, headings as bold lines (the page keeps its own
    structure), images pointed at the generated folder, links to the run
    folders' files as plain text."""
    out, skipping = [], bool(only)
    for line in text.splitlines():
        heading = re.match(r"^(#+)\s+(.*)$", line)
        if heading:
            level, title = len(heading.group(1)), heading.group(2)
            if level <= 2:
                skipping = title in drop or bool(only) and title not in only
                if title in only:
                    continue
            if skipping or level == 1 and not out:
                continue
            out.append(f"**{title}**")
            continue
        if skipping:
            continue
        line = re.sub(r"!\[([^]]*)\]\((?!https?:)([^)]+)\)",
                      lambda m: f"![{m.group(1)}]({folder}/{m.group(2)})", line)
        line = re.sub(r"(?<!!)\[([^]]+)\]\((?!https?:)[^)]+\)", r"`\1`", line)
        out.append(line)
    return "\n".join(out)


class Generated(_MarkdownDirective):
    """``generated STUDY``: options ``file`` (Markdown in the study's
    snapshot, default report.md), ``drop`` (comma-separated sections to
    leave out) or ``only`` (the sections to keep, without their headings),
    ``images`` (a glob of figures to show after it)."""

    required_arguments = 1
    option_spec = {"file": directives.unchanged, "drop": directives.unchanged,
                   "only": directives.unchanged, "images": directives.unchanged}

    def markdown(self):
        study = self.arguments[0]
        folder = RESULTS / study
        snapshot = folder / "snapshot.json"
        source = folder / self.options.get("file", "report.md")
        if not snapshot.exists() or not source.exists():
            command = f"python docs/results.py --study {study}"
            logger.warning(f"study {study} has no snapshot ({source.relative_to(RESULTS.parent)}"
                           f" is missing): make it with {command}",
                           location=self.get_location())
            return (f":::{{note}}\nThis part shows the study `{study}`, whose reference "
                    f"results are not in this build. Make them with\n\n```bash\n{command}"
                    f"\n```\n\nand build again.\n:::")
        self.env.note_dependency(str(source))
        self.env.note_dependency(str(snapshot))
        # Comma-separated titles; a title with a comma in it ("The neural
        # controller, window by window") is named whole.
        drop, only = ({name.strip() for name in self.options.get(key, "").split(",")
                       if name.strip()} | ({self.options[key].strip()} if key in self.options
                                            else set()) for key in ("drop", "only"))
        # Images are named relative to this page, wherever the folder is.
        here = Path(self.env.doc2path(self.env.docname)).parent
        link = Path(os.path.relpath(folder, here)).as_posix()
        stamp = json.loads(snapshot.read_text())
        parts = [f"*The reference results: measured at commit {stamp['commit']} on "
                 f"{stamp['date']} (`{stamp['runs']}`, {_duration(stamp['refresh_s'])} on 2 "
                 f"cores); refreshed by `{stamp['command']}`.*",
                 _study_markdown(source.read_text(), link, drop, only)]
        pattern = self.options.get("images")
        if pattern:
            for image in sorted(folder.rglob("*.png")):
                relative = image.relative_to(folder).as_posix()
                if fnmatch.fnmatch(relative, pattern):
                    parts.append(f"![{image.stem}]({link}/{relative})")
        return "\n\n".join(parts)


def _results_module():
    """``docs/results.py`` (the snapshots' registry), imported by path."""
    import importlib.util
    spec = importlib.util.spec_from_file_location("docs_results", RESULTS.parent / "results.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


class ReproductionStatus(_MarkdownDirective):
    """``reproduction-status``: the README's status paragraph, from the
    reproduction's snapshot."""

    def markdown(self):
        self.env.note_dependency(str(RESULTS / "reproduce" / "claims.csv"))
        self.env.note_dependency(str(RESULTS / "reproduce" / "snapshot.json"))
        return _results_module().readme_status(RESULTS, details=False)


class ReferenceResults(_MarkdownDirective):
    """``reference-results``: every snapshot in ``docs/results/``: the
    study, what it runs, its refresh's time on 2 cores, commit and date."""

    def markdown(self):
        rows, total = [], 0
        for snapshot in sorted(RESULTS.glob("*/snapshot.json")):
            self.env.note_dependency(str(snapshot))
            stamp = json.loads(snapshot.read_text())
            total += stamp["refresh_s"]
            rows.append((f"`{stamp['study']}`", f"`{stamp['runs']}`",
                         _duration(stamp["refresh_s"]), stamp["commit"], stamp["date"]))
        rows.append(("all", f"`python docs/results.py` ({len(rows)} studies)",
                     _duration(total), "", ""))
        return _table(["study", "what it runs", "refresh on 2 cores", "commit", "date"], rows)


def _duration(seconds: float) -> str:
    return f"{seconds:.0f} s" if seconds < 120 else f"{seconds / 60:.0f} min"


def _reexported_data_doc(app, what, name, obj, options, lines):
    """A constant that ``drake_contact`` re-exports (``FAULT_KINDS``) is
    documented by the ``#:`` comment where it is defined, not by its type's
    docstring."""
    import drake_contact
    from sphinx.pycode import ModuleAnalyzer

    short = name.rpartition(".")[2]
    module = drake_contact._MODULE_OF.get(short)
    if what != "data" or not name.startswith("drake_contact.") or module is None:
        return
    candidates = [module]
    package = importlib.import_module(module)
    if hasattr(package, "__path__"):  # defined in one of the package's modules
        candidates += [f"{module}.{info.name}" for info in pkgutil.iter_modules(package.__path__)]
    for candidate in candidates:
        comment = ModuleAnalyzer.for_module(candidate).find_attr_docs().get(("", short))
        if comment:
            lines[:] = list(comment)
            return


def _check_sections(app, env):
    from drake_contact.scenario import Scenario

    from sphinx.util import logging

    listed = getattr(env, _SECTIONS_LISTED, set())
    for name, hint in typing.get_type_hints(Scenario).items():
        if _section(hint) is not None and name not in listed:
            logging.getLogger(__name__).warning(
                f"the scenario section {name!r} is on no page (scenario-fields)")


def _merge_sections(app, env, docnames, other):
    setattr(env, _SECTIONS_LISTED,
            getattr(env, _SECTIONS_LISTED, set()) | getattr(other, _SECTIONS_LISTED, set()))


def setup(app):
    app.add_directive("scenario-fields", ScenarioFields)
    app.add_directive("station-signals", StationSignals)
    app.add_directive("measured-signals", MeasuredSignalsTable)
    app.add_directive("scores", ScoresTable)
    app.add_directive("generated", Generated)
    app.add_directive("reference-results", ReferenceResults)
    app.add_directive("reproduction-status", ReproductionStatus)
    app.add_directive("policy-spaces", PolicySpaces)
    app.add_directive("thesis-claims", ThesisClaims)
    app.connect("autodoc-process-docstring", _reexported_data_doc)
    app.connect("env-check-consistency", _check_sections)
    app.connect("env-merge-info", _merge_sections)
    return {"parallel_read_safe": True, "parallel_write_safe": True, "version": "1"}

"""YAML is bounded (issue 19): an alias bomb or an oversized ruleset, merge file or manifest is
refused by a limit with one clear line, and reading is linear in the document's size (each node
is indexed once, however many aliases name it)."""
from __future__ import annotations

import concurrent.futures

import pytest

from allorules.cli import main
from allorules.errors import RulesetError
from allorules.rules import located_yaml
from allorules.rules.located_yaml import MAX_VALUES, read_located_yaml


def alias_bomb(levels: int = 9, width: int = 9, *, key: str = "rules") -> str:
    """'Billion laughs': each level lists the previous one ``width`` times (width**levels values)."""
    lines = [f"a0: &a0 [{', '.join(['x'] * width)}]"]
    for level in range(1, levels):
        lines.append(f"a{level}: &a{level} [{', '.join([f'*a{level - 1}'] * width)}]")
    lines.append(f"{key}: *a{levels - 1}")
    return "\n".join(lines) + "\n"


def within(seconds: float, function, *args):
    """Call ``function`` in a thread; a safety net so that a regression fails instead of hanging
    the suite. The tests assert WHAT stopped the work (a limit's message), never how fast."""
    with concurrent.futures.ThreadPoolExecutor(1) as pool:
        future = pool.submit(function, *args)
        try:
            return future.result(timeout=seconds)
        except concurrent.futures.TimeoutError:
            pytest.fail(f"still running after {seconds} s: the document was not bounded")


def refusal(function, *args) -> str:
    def call():
        try:
            function(*args)
        except RulesetError as error:
            return str(error)
        return None
    message = within(120, call)
    assert message is not None, "the document was accepted"
    return message


def test_an_alias_bomb_ruleset_is_refused_by_the_values_limit(tmp_path):
    path = tmp_path / "bomb.yaml"
    path.write_text("name: bomb\nregions: [head]\n" + alias_bomb())
    message = refusal(read_located_yaml, path)
    assert f"more than {MAX_VALUES:,} values through its aliases" in message
    assert message.startswith(f"{path}:")


def test_an_alias_bomb_manifest_is_refused(tmp_path):
    from allorules.runs.batch import ManifestError, load_manifest

    path = tmp_path / "herd.yaml"
    path.write_text("ratios: [2]\nrulesets: [global]\n" + alias_bomb(key="meshes"))
    with pytest.raises(ManifestError, match="values through its aliases"):
        within(120, load_manifest, path)


def test_an_alias_bomb_merge_file_is_refused(tmp_path):
    from allorules.segment.labels_io import read_merge_file

    path = tmp_path / "merge.yaml"
    path.write_text(alias_bomb(key="head"))
    message = refusal(read_merge_file, path, 24)
    assert "is not an integer" in message


def test_the_command_line_refuses_a_bomb_in_one_line(tmp_path, capsys):
    path = tmp_path / "bomb.yaml"
    path.write_text("name: bomb\n" + alias_bomb())
    assert within(120, main, ["ruleset", "check", str(path)]) == 1
    error = capsys.readouterr().err
    assert "values through its aliases" in error and "Traceback" not in error


@pytest.mark.parametrize("kind", ["ruleset", "merge file", "manifest"])
def test_an_oversized_file_is_refused_before_it_is_read(tmp_path, monkeypatch, kind):
    from allorules.runs.batch import load_manifest
    from allorules.segment.labels_io import read_merge_file

    path = tmp_path / "large.yaml"
    path.write_text("# padding\n" * 250_000)   # 2.5 MB of comments
    read = {"ruleset": lambda: read_located_yaml(path), "merge file": lambda: read_merge_file(path, 24),
            "manifest": lambda: load_manifest(path)}[kind]
    message = refusal(read)
    assert f"the {kind} is 2.5 MB; allorules reads YAML files of at most 2 MB" in message
    monkeypatch.setenv("ALLORULES_YAML_MAX_BYTES", "3000000")   # a user with an unusual file can raise it
    with pytest.raises(RulesetError) as caught:
        read()
    assert "MB" not in str(caught.value)


def test_a_document_with_too_many_plain_values_is_refused_without_mentioning_aliases(tmp_path, monkeypatch):
    monkeypatch.setenv("ALLORULES_YAML_MAX_VALUES", "1000")
    path = tmp_path / "long.yaml"
    path.write_text("rules:\n" + "".join(f"  - {index}\n" for index in range(1500)))
    message = refusal(read_located_yaml, path)
    assert "more than 1,000 values (a ruleset is usually a few hundred)" in message and "alias" not in message


def test_a_value_containing_itself_is_refused(tmp_path):
    path = tmp_path / "loop.yaml"
    path.write_text("rules: &loop [*loop]\n")
    assert "contains it" in refusal(read_located_yaml, path)


def test_indexing_visits_each_node_once_however_many_aliases_name_it(tmp_path, monkeypatch):
    """Six levels of nine: 531,441 values when expanded, 60 nodes written. The limit raised so
    that the document is read: the locations recorded stay proportional to the file."""
    monkeypatch.setenv("ALLORULES_YAML_MAX_VALUES", "10000000")
    calls = []
    original = located_yaml._location
    monkeypatch.setattr(located_yaml, "_location", lambda path, node: calls.append(1) or original(path, node))
    path = tmp_path / "wide.yaml"
    path.write_text(alias_bomb(levels=6))
    document = within(120, read_located_yaml, path)
    assert len(document.data["rules"]) == 9
    assert len(calls) < 200   # 60 nodes and 60 alias uses; not one per expanded value


def test_anchors_and_merge_keys_still_work_with_their_lines(tmp_path):
    path = tmp_path / "shared.yaml"
    path.write_text("defaults: &defaults {measure: length, exponent: 0.36}\n"
                    "rules:\n"
                    "  - {id: a, region: neck, <<: *defaults}\n"
                    "  - id: b\n"
                    "    region: head\n"
                    "    <<: *defaults\n")
    document = read_located_yaml(path)
    assert [rule["exponent"] for rule in document.data["rules"]] == [0.36, 0.36]
    assert document.at("rules", 1, "region").line == 5
    assert document.at("rules", 1, "<<").line == 1   # the shared values are where the anchor is


def test_a_duplicate_key_inside_an_anchor_is_reported_once(tmp_path):
    path = tmp_path / "twice.yaml"
    path.write_text("base: &base {a: 1, a: 2}\none: *base\ntwo: *base\n")
    with pytest.raises(RulesetError) as caught:
        read_located_yaml(path)
    assert "key 'a' is given twice" in str(caught.value) and "more problem" not in str(caught.value)


def test_nesting_thousands_deep_is_one_line_in_merge_and_labels_files(tmp_path):
    from allorules.body import Body
    from allorules.errors import SegmentationError
    from allorules.segment.labels_io import read_labels, read_merge_file

    merge = tmp_path / "deep.yaml"
    merge.write_text("head: " + "[" * 5000 + "]" * 5000 + "\n")
    assert "nests too deeply" in refusal(read_merge_file, merge, 24)
    labels = tmp_path / "deep.json"
    labels.write_text("[" * 100_000 + "]" * 100_000)
    import numpy as np

    body = Body(np.eye(3), np.array([[0, 1, 2]]))
    with pytest.raises(SegmentationError, match="nests thousands of levels deep"):
        read_labels(labels, body)

"""Every file the tools read, mutated at random: a valid result or one typed error line (issue 12).

Three readers, each fed a valid file changed in a few random places (a value replaced by
another type, a huge or non-finite number, a long string or a deep list; a key removed, an
unknown key added; the text cut or garbled):

- plant-model files (:func:`~galvo_sysid.model.files.load_model`, what ``--model`` and the
  nodes' ``model`` parameter read);
- node parameter files (``--sysid-params`` / ``--watchdog-params``, read by
  :func:`~galvo_sysid.field.parameter_file.load_node_parameters`);
- a bag's ``metadata.yaml`` (:class:`~galvo_sysid.field.bags.reader.BagReader`: open, info and
  every move half read).

Each must return a value (and a model that loads must also save and load again to the same
dictionary) or raise a :class:`~galvo_sysid.errors.GalvoSysidError` whose message is one line;
never another exception. Most generated files are near-valid, so the checks behind the
parser (types, ranges, the effect registry, strict sections) are reached, not only the YAML
parser.
"""

from __future__ import annotations

import copy
import math
import shutil
from pathlib import Path
from typing import Any

import pytest
import yaml
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from galvo_sysid.errors import GalvoSysidError
from galvo_sysid.field.bags.reader import BagReader
from galvo_sysid.field.parameter_file import load_node_parameters
from galvo_sysid.model.files import load_model, model_from_dict, model_to_dict
from galvo_sysid.model.paper import PAPER_MODEL
from galvo_sysid.sim.family import random_scanner

CONFIG = Path(__file__).resolve().parents[1] / 'config'
NOMINAL = Path(__file__).resolve().parents[1] / 'bags' / 'nominal'

SETTINGS = settings(max_examples=120, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.too_slow,
                                           HealthCheck.function_scoped_fixture])

_values = st.one_of(
    st.none(), st.booleans(), st.integers(-10**30, 10**30),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0, -1, 1e-300, 1e300, -1e200, 2**63, '', '123', 'nan', '.inf', 'x' * 5000]),
    st.text(max_size=30),
    st.lists(st.floats(-1e6, 1e6), max_size=5),
    st.builds(lambda: [[[[[[1]]]]]]),  # a fresh object: mutations must not share it
    st.dictionaries(st.text(max_size=8), st.integers(), max_size=3),
)


def _paths(tree: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    """Every key path of a nested dict/list (the places a mutation can hit)."""
    out: list[tuple[Any, ...]] = []
    items = tree.items() if isinstance(tree, dict) else (
        enumerate(tree) if isinstance(tree, list) else ())
    for key, value in items:
        out.append((*prefix, key))
        out.extend(_paths(value, (*prefix, key)))
    return out


@st.composite
def _mutated(draw: st.DrawFn, tree: Any) -> Any:
    tree = copy.deepcopy(tree)
    for _ in range(draw(st.integers(1, 3))):
        paths = _paths(tree)
        if not paths:
            break
        path = draw(st.sampled_from(paths))
        parent = tree
        for key in path[:-1]:
            parent = parent[key]
        kind = draw(st.sampled_from(['replace', 'replace', 'replace', 'remove', 'add']))
        if kind == 'replace':
            parent[path[-1]] = draw(_values)
        elif kind == 'remove':
            del parent[path[-1]]
        elif isinstance(parent, dict):
            parent[draw(st.sampled_from(['lag_time_constnt', 'extra', 'modes ', 'k0']))] = \
                draw(_values)
        else:
            parent.append(draw(_values))
    return tree


@st.composite
def _texts(draw: st.DrawFn, tree: Any) -> str:
    """YAML of a mutated tree; sometimes cut short or with a few bytes garbled."""
    text = yaml.safe_dump(draw(_mutated(tree)), sort_keys=False, allow_unicode=True)
    damage = draw(st.sampled_from(['none', 'none', 'none', 'cut', 'garble']))
    if damage == 'cut':
        text = text[:draw(st.integers(0, len(text)))]
    elif damage == 'garble':
        chars = list(text)
        for _ in range(draw(st.integers(1, 5))):
            if chars:
                chars[draw(st.integers(0, len(chars) - 1))] = draw(
                    st.sampled_from(['&', '*', ':', '{', '[', '\t', '\x00', '%', '"', '\n']))
        text = ''.join(chars)
    return text


def _one_line(err: GalvoSysidError) -> None:
    text = str(err)
    # what refused it (the YAML parser, or a check behind it), for --hypothesis-show-statistics
    event('refused: ' + ('YAML' if 'YAML' in text else type(err).__name__))
    assert text
    assert '\n' not in text, text
    assert len(text) < 2000, text


MODELS = [model_to_dict(PAPER_MODEL), model_to_dict(random_scanner(3).model)]


@SETTINGS
@given(st.sampled_from([0, 1]).flatmap(lambda i: _texts(MODELS[i])))
def test_mutated_model_files(tmp_path_factory: pytest.TempPathFactory, text: str) -> None:
    path = tmp_path_factory.mktemp('model') / 'scanner.yaml'
    path.write_text(text)
    try:
        model = load_model(path)
    except GalvoSysidError as err:
        _one_line(err)
        return
    event('loaded')
    again = model_from_dict(model_to_dict(model))  # what loads also saves and loads back
    assert model_to_dict(again) == model_to_dict(model)
    assert all(math.isfinite(w) and w > 0 for w in model.modal.natural_frequencies)


PARAMETER_FILES = {node: yaml.safe_load((CONFIG / f'{node}.yaml').read_text())
                   for node in ('sysid', 'watchdog')}


@SETTINGS
@given(st.sampled_from(['sysid', 'watchdog']).flatmap(
    lambda n: st.tuples(st.just(n), _texts(PARAMETER_FILES[n]))))
def test_mutated_node_parameter_files(tmp_path_factory: pytest.TempPathFactory,
                                      case: tuple[str, str]) -> None:
    node, text = case
    path = tmp_path_factory.mktemp('params') / f'{node}.yaml'
    path.write_text(text)
    try:
        values = load_node_parameters(path, node)
    except GalvoSysidError as err:
        _one_line(err)
        return
    event('loaded')
    assert isinstance(values, dict)
    for value in values.values():  # whatever is accepted is a plain, finite value
        for v in value if isinstance(value, list) else [value]:
            assert not (isinstance(v, float) and not math.isfinite(v)), values


METADATA = yaml.safe_load((NOMINAL / 'metadata.yaml').read_text())


@settings(SETTINGS, max_examples=60)
@given(_texts(METADATA))
def test_mutated_bag_metadata(tmp_path_factory: pytest.TempPathFactory, text: str) -> None:
    bag = tmp_path_factory.mktemp('bag') / 'nominal'
    bag.mkdir()
    for storage in NOMINAL.glob('*.mcap'):
        (bag / storage.name).symlink_to(storage)
    (bag / 'metadata.yaml').write_text(text)
    try:
        with BagReader(bag) as reader:
            info = reader.info
            halves = sum(1 for _ in reader.move_halves())
    except GalvoSysidError as err:
        _one_line(err)
        return
    finally:
        shutil.rmtree(bag.parent, ignore_errors=True)
    event('read')
    assert halves <= 800  # never more than the storage holds, whatever metadata says
    assert info is not None

"""The floors of docs/layers.md: import-linter's contracts in pyproject.toml hold, the import graph has no cycle
(of modules, or of floors through the command line), and an upward import breaks them."""
import ast
import copy
import re
from pathlib import Path

import grimp
import numpy as np
import pytest
from importlinter import api
from importlinter.application.use_cases import lint_imports
from importlinter.contracts.forbidden import ForbiddenContract
from importlinter.contracts.independence import IndependenceContract
from importlinter.contracts.layers import LayersContract
from importlinter.contracts.protected import ProtectedContract
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

CONFIG = Path(__file__).resolve().parent.parent / "pyproject.toml"
CONTRACT_TYPES = {"layers": LayersContract, "forbidden": ForbiddenContract, "protected": ProtectedContract,
                  "independence": IndependenceContract}
COMMAND_LINE = ("studies.commands", "studies.cli")
ROOT = CONFIG.parent
MODULE_NAME = re.compile(r"^[A-Za-z_]\w*(\.\w+)+(:\w+)?$|^[A-Za-z_]\w*:\w+$")  # a.b, a.b:name, a:name


@pytest.fixture(scope="module")
def config() -> dict:
    return api.read_configuration(str(CONFIG))


@pytest.fixture(scope="module")
def graph(config) -> grimp.ImportGraph:
    return grimp.build_graph(*config["session_options"]["root_packages"], cache_dir=None)


def broken_contracts(graph, config) -> list[str]:
    """Ids of the pyproject.toml contracts that ``graph`` breaks."""
    broken = []
    for options in config["contracts_options"]:
        contract = CONTRACT_TYPES[options["type"]](name=options["name"], session_options=config["session_options"],
                                                   contract_options=options)
        if not contract.check(copy.deepcopy(graph), verbose=False).kept:  # check() drops the ignored imports
            broken.append(options["id"])
    return broken


def cycles(nodes, edges) -> list[list[str]]:
    """The strongly connected components of more than one node: each holds at least one cycle."""
    index = {n: i for i, n in enumerate(sorted(nodes))}
    rows, cols = zip(*((index[a], index[b]) for a, b in edges)) if edges else ((), ())
    adjacency = csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(index), len(index)))
    count, label = connected_components(adjacency, directed=True, connection="strong")
    members = [[] for _ in range(count)]
    for name, k in zip(sorted(nodes), label):
        members[k].append(name)
    return [m for m in members if len(m) > 1]


def string_import_edges(module: str, source: str, modules) -> set:
    """(module, target) for every string literal passed to a call in ``source`` that names one of ``modules``,
    whole: what ``importlib.import_module("a.b")``, ``Forward(simulator="a.b:function")`` or a lazy
    ``Names("a.b:NAME")`` loads, which the import statements (all grimp reads) do not show.  A name merely kept
    as a value (a default in a dataclass field) loads nothing and is no edge."""
    edges = set()
    for call in (n for n in ast.walk(ast.parse(source)) if isinstance(n, ast.Call)):
        for node in [*call.args, *(k.value for k in call.keywords)]:
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and MODULE_NAME.match(node.value):
                target = node.value.split(":")[0]
                if target in modules and target != module:
                    edges.add((module, target))
    return edges


def source_of(module: str) -> str:
    path = ROOT.joinpath(*module.split("."))
    path = path / "__init__.py" if path.is_dir() else path.with_suffix(".py")
    return path.read_text()


def module_edges(graph) -> set:
    """The import graph's edges, import statements (lazy ones included) and string imports alike."""
    edges = {(m, d) for m in graph.modules for d in graph.find_modules_directly_imported_by(m) if d != m}
    for m in graph.modules:
        edges |= string_import_edges(m, source_of(m), graph.modules)
    return edges


def floor(module: str) -> str:
    """The floor a module stands on: its top-level package, the command line counted as a floor of its own."""
    return "command line" if module.startswith(COMMAND_LINE) else module.split(".")[0]


def floor_edges(graph) -> set:
    return {(floor(a), floor(b)) for a, b in module_edges(graph) if floor(a) != floor(b)}


def test_lint_imports_keeps_every_contract(capsys):
    assert lint_imports(config_filename=str(CONFIG), cache_dir=None, no_logo=True), capsys.readouterr().out


def test_the_graph_is_the_projects_and_keeps_every_contract(graph, config):
    assert {"mpm.params", "studies.commands.figures", "paper_figures._landscape_data"} <= graph.modules
    assert broken_contracts(graph, config) == []


def test_no_module_cycles_and_no_cycle_through_the_command_line(graph):
    assert cycles(graph.modules, module_edges(graph)) == []
    floors = {floor(m) for m in graph.modules}
    assert "command line" in floors and cycles(floors, floor_edges(graph)) == []


@pytest.mark.parametrize("importer, imported, contract", [
    ("poiseuille.flow", "similarity.space", "floors"),
    ("mpm.solver", "surrogate.theta", "floors"),
    ("poiseuille.loss", "mpm.batch", "floors"),
    ("surrogate.theta", "mpm.store", "value-types"),
    ("mpm.params", "mpm.camera", "value-types-stand-alone"),
    ("paper_figures._landscape_data", "studies.commands.context", "command-line-on-top"),
    ("studies.landscapes", "paper_figures._plot", "figures-for-the-command-line"),
    ("similarity.posterior", "mpm.store", "forward-model-seam"),
    ("studies.calibration", "mpm.batch", "forward-model-seam"),
])
def test_an_upward_import_breaks_a_contract(graph, config, importer, imported, contract):
    upward = copy.deepcopy(graph)
    upward.add_import(importer=importer, imported=imported)
    assert contract in broken_contracts(upward, config)


def test_the_cycle_checks_see_a_circle(graph):
    # the circle that paper_figures once closed through the command line, and a module circle inside mpm
    upward = copy.deepcopy(graph)
    upward.add_import(importer="paper_figures._landscape_data", imported="studies.commands.context")
    assert ["command line", "paper_figures"] in cycles({floor(m) for m in upward.modules}, floor_edges(upward))
    upward.add_import(importer="mpm.params", imported="mpm.solver")
    assert any("mpm.params" in c and "mpm.solver" in c for c in cycles(upward.modules, module_edges(upward)))


def test_string_imports_are_edges_and_an_import_module_circle_is_seen(graph):
    edges = module_edges(graph)
    assert ("mpm.runtime", "mpm.native_engine") in edges  # importlib.import_module("mpm.native_engine")
    assert ("studies.commands.context", "similarity.estimate") in edges  # Names("similarity.estimate:PRESETS")
    # a circle closed only by import_module, as mpm.constitutive -> runtime -> native_engine -> constitutive was
    lazy = string_import_edges("mpm.native_engine", 'import importlib\n\ndef f():\n'
                               '    return importlib.import_module("mpm.constitutive")\n', graph.modules)
    assert lazy == {("mpm.native_engine", "mpm.constitutive")}
    assert any({"mpm.constitutive", "mpm.runtime", "mpm.native_engine"} <= set(c)
               for c in cycles(graph.modules, edges | lazy))

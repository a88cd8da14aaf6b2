"""The public plugin API is versioned: it equals the committed snapshot of its version, the changelog and the API page
name that version, and the page lists every public name."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest

from clods_bench import api
from clods_bench.api_version import API_VERSION, api_version_problem, parse_api_version
from tests.api_surface import api_surface, surface_changes

ROOT = Path(__file__).resolve().parents[1]
SNAPSHOT = Path(__file__).parent / "data" / "plugin_api" / f"{API_VERSION}.json"
REWRITE = f"python -m tests.api_surface {SNAPSHOT.relative_to(ROOT)}"


def test_the_api_is_its_versions_snapshot() -> None:
    assert SNAPSHOT.is_file(), f"no snapshot of plugin API {API_VERSION}: write it with `{REWRITE}`"
    changes = surface_changes(json.loads(SNAPSHOT.read_text()), api_surface())
    assert not changes, (
        f"the public plugin API differs from the snapshot of {API_VERSION}: {changes}. Bump API_VERSION in "
        f"clods_bench/api_version.py (minor: additions only; major: a change or removal, after a deprecation), name the "
        f"change in CHANGELOG.md, and write the new snapshot with `{REWRITE}`"
    )


def test_changes_are_found() -> None:
    """The comparison sees a removed name, a changed field and a changed hook; a field added to RunConfig is allowed."""
    base = api_surface()
    edited = copy.deepcopy(base)
    del edited["names"]["Sphere"]
    edited["names"]["PluginSpec"]["fields"]["learned"]["type"] = "int"
    edited["hooks"]["clods_bench_scenes"]["firstresult"] = True
    edited["names"]["RunConfig"]["fields"]["brand_new"] = {"type": "int", "required": False}
    assert surface_changes(base, edited) == [
        "names: PluginSpec changed (fields)",
        "names: Sphere removed",
        "hooks: clods_bench_scenes changed (firstresult)",
    ]
    del edited["names"]["RunConfig"]["fields"]["seeds"]
    assert any(c.startswith("names: RunConfig.seeds removed or changed") for c in surface_changes(base, edited))


def test_every_public_name_exists_and_is_documented() -> None:
    page = (ROOT / "docs" / "plugins" / "api.md").read_text()
    assert f"plugin API {API_VERSION}" in page
    missing = [name for name in api.__all__ if f"`{name}`" not in page]
    assert not missing, f"docs/plugins/api.md does not name {missing}"
    assert all(hasattr(api, name) for name in api.__all__)


def test_the_changelog_names_the_api_version() -> None:
    text = " ".join((ROOT / "CHANGELOG.md").read_text().lower().split())
    assert f"plugin api {API_VERSION}" in text


@pytest.mark.parametrize(
    "declared, problem",
    [
        ("1.0", None),
        ("1.1", None),
        ("1.2", None),
        ("1.3", "it needs plugin API 1.3; this release offers plugin API 1.2 (and loads plugins for 1.0 to 1.2)"),
        ("2.0", "it needs plugin API 2.0; this release offers plugin API 1.2 (and loads plugins for 1.0 to 1.2)"),
        ("0.9", "it needs plugin API 0.9; this release offers plugin API 1.2 (and loads plugins for 1.0 to 1.2)"),
        (1.1, "CLODS_BENCH_API = 1.1 is not a version like '1.2'; this release offers plugin API 1.2 (and loads plugins for 1.0 to 1.2)"),
        ("1.1.0", "CLODS_BENCH_API = '1.1.0' is not a version like '1.2'; this release offers plugin API 1.2 (and loads plugins for 1.0 to 1.2)"),
    ],
)
def test_declared_api_versions(declared: object, problem: str | None) -> None:
    assert parse_api_version(API_VERSION) == (1, 2)
    assert api_version_problem(declared) == problem

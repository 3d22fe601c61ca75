"""docs/configuration.md is what tools/gen_config_reference.py writes from the config dataclasses."""

from __future__ import annotations

import importlib.util

from helpers import REPO


def _tool():  # noqa: ANN202
    spec = importlib.util.spec_from_file_location("gen_config_reference", REPO / "tools" / "gen_config_reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)  # type: ignore[union-attr]
    return module


def test_the_configuration_page_is_current():
    page = (REPO / "docs" / "configuration.md").read_text()
    assert page == _tool().render(), "run: python tools/gen_config_reference.py"


def test_every_section_a_config_file_uses_is_documented_with_its_keys():
    import yaml

    tool = _tool()
    documented = tool.sections()
    for path in sorted((REPO / "config").glob("*.yaml")):
        for name, values in (yaml.safe_load(path.read_text()) or {}).items():
            assert name in documented, (path.name, name)
            text = tool.render()
            for key in values or {}:
                assert f"| `{key}` |" in text, (path.name, name, key)


def test_the_page_documents_exactly_the_sections_a_config_may_have():
    from changing_slam_ros.config import CONFIG_SECTIONS

    assert sorted(_tool().sections()) == sorted(CONFIG_SECTIONS)

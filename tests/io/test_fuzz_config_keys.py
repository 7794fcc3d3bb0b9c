"""A config file's top-level keys are its sections only (found by fuzzing with atheris)."""

from __future__ import annotations

from pathlib import Path

import pytest

from semslam.config import load_config
from semslam.errors import ConfigError


@pytest.mark.parametrize(
    "text",
    [
        '{"_cli_parse_args": [0]}',  # was SystemExit from argparse
        '{"_cli_parse_args": ["--help"]}',  # was the help text and SystemExit
        '{"_env_prefix": 4}',  # was TypeError
        '{"_env_file": 5}',  # was TypeError
        '{"_secrets_dir": "' + "a" * 300 + '"}',  # was OSError (file name too long)
        '{"_case_sensitive": "x"}',  # was taken without a word
    ],
)
def test_a_settings_keyword_in_a_config_file_is_refused(tmp_path: Path, text: str) -> None:
    path = tmp_path / "c.json"
    path.write_text(text)
    key = text.split('"')[1]
    with pytest.raises(ConfigError, match=f"c.json: {key}: not a setting semslam knows"):
        load_config(path)


def test_an_unknown_section_is_still_named(tmp_path: Path) -> None:
    path = tmp_path / "c.json"
    path.write_text('{"mapping": {"robust": "none"}, "mapingg": {}}')
    with pytest.raises(ConfigError, match="c.json: mapingg: not a setting semslam knows"):
        load_config(path)

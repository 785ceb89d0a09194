"""Shared control: the assistance stage between the person's command and the safety layer."""

from robchair.assistance.stage import MODES, AssistConfig, AssistedSource, check_mode

__all__ = ["MODES", "AssistConfig", "AssistedSource", "check_mode"]

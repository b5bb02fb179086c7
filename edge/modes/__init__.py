"""The modes of the device: range finder, blind aid, area guard.

``Mode`` is the one list of them: the config's ``mode`` key, ``cmd/mode`` and Home Assistant's
select all take it from here.
"""

from typing import Literal, get_args

Mode = Literal["rangefinder", "blindaid", "guard"]
MODES: tuple[str, ...] = get_args(Mode)

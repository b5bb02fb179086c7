"""The modes of the device: range finder, blind aid, area guard."""

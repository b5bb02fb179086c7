"""The blind aid: its pure logic (:mod:`.logic`: zones in, cues out), its sound (:mod:`.sound`:
cues to samples, sinks) and its runner on the rig (:mod:`.runner`: threads, the unit, the button)."""

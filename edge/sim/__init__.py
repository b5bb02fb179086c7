"""The simulator: scenes (rooms, boxes, movers), ray casting and rendering of the virtual rig."""

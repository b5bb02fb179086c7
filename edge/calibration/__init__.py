"""Calibration of the rig's lasers (and camera) from flat-target captures.

- :mod:`edge.calibration.spots`: the board's spots in a recording's zones, found and placed;
- :mod:`edge.calibration.fit`: the least-squares fit itself (pure: spots in, rays out);
- :mod:`edge.calibration.file`: the fit's result, :class:`~edge.calibration.file.Calibration`, and
  its file format ``edge-calibration/1`` (read, write);
- :mod:`edge.calibration.limits`: what a fit needs (distances, span), light to import;
- :mod:`edge.calibration.report`: a calibration told to people;
- :mod:`edge.calibration.session`: ``cmd/calibrate``, the interactive session on the device that
  takes a target's rests in order and fits them;
- :mod:`edge.calibration.in_use`: which rig ranging believes (the configured rig with its
  calibration applied).

The command line, ``edge calibrate``, is :mod:`edge.cli.calibrate`.
"""

"""What a calibration needs, shared by the fit and the checks of a ``cmd/calibrate`` request.

Kept apart from the fit so that the command checks (``edge.commands``) read them without importing
OpenCV and the fit.
"""

MIN_POINTS = 3  # distinct distances a laser's spot must be found at: a line through 2 shows no error
MIN_SPAN = 1.5  # farthest / nearest distance: less cannot tell a laser's origin from its direction

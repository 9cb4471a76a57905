"""One look for every view of a Scenario (viewer, report, plots): colours, class and category legends.

The viewer's page gets these through ``/api/scenario`` (:func:`page_style`), so the browser, the
report and the static plots use the same colours and the same words.
"""

from __future__ import annotations

from typing import Any

from deepcrashtest.scenario import TRAJECTORY_CLASSES, Vehicle

EGO_COLOUR = "#d32f2f"
UNCLASSIFIED_COLOUR = "#78909c"
CLASS_COLOURS: dict[str, str] = dict(
    zip(TRAJECTORY_CLASSES, ("#1e88e5", "#00acc1", "#3949ab", "#fbc02d", "#fb8c00", "#8e24aa", "#6d4c41"), strict=True)
)
#: What the trajectory classes of the reference paper mean (see ``trajectory.classify``).
CLASS_DESCRIPTIONS: dict[str, str] = {
    "D0T1": "same direction, in view from the start",
    "D0T2": "same direction, overtakes from behind (enters later)",
    "D0T3": "same direction, enters later ahead",
    "D1T1": "oncoming, in view from the start, passed by the ego",
    "D1T2": "oncoming, in view from the start, not passed",
    "D1T3": "oncoming, enters later, passed",
    "D1T4": "oncoming, enters later, not passed",
}
#: The same in a few words, for legends.
CLASS_SHORT: dict[str, str] = {
    "D0T1": "same direction, from the start",
    "D0T2": "same direction, overtakes",
    "D0T3": "same direction, enters ahead",
    "D1T1": "oncoming, from the start, passed",
    "D1T2": "oncoming, from the start, not passed",
    "D1T3": "oncoming, enters later, passed",
    "D1T4": "oncoming, enters later, not passed",
}
#: How each road-user category is drawn from above: box (cars, vans), long box with a cab line (truck,
#: bus), a narrow diamond (two-wheelers with their rider), a disc (pedestrian).
CATEGORY_SHAPES: dict[str, str] = {
    "car": "box",
    "van": "box",
    "truck": "long box",
    "bus": "long box",
    "motorcycle": "diamond",
    "bicycle": "diamond",
    "pedestrian": "disc",
}
OBSERVED_NOTE = "solid: seen in the video; dashed/faded: extrapolated, lead-in or step-back (not observed)"


def vehicle_colour(v: Vehicle, ego_id: int = 0) -> str:
    """The colour of a vehicle: the ego's, or its trajectory class's."""
    if v.id == ego_id:
        return EGO_COLOUR
    return CLASS_COLOURS.get(v.trajectory_class or "", UNCLASSIFIED_COLOUR)


def page_style() -> dict[str, Any]:
    """Colours and legend texts for the viewer page."""
    return {
        "ego": EGO_COLOUR,
        "unclassified": UNCLASSIFIED_COLOUR,
        "classes": CLASS_COLOURS,
        "class_descriptions": CLASS_DESCRIPTIONS,
        "class_short": CLASS_SHORT,
        "category_shapes": CATEGORY_SHAPES,
        "observed_note": OBSERVED_NOTE,
    }

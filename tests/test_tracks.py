"""A laser's spot followed across a zone's frame groups (edge.tracks.follow): sightings as near as
their placing's noise allows are one spot; a blob of one group among several is not kept."""

from __future__ import annotations

import numpy as np

from edge.tracks import FrameGroup, follow, pooled_frames
from edge.vision import Candidate


def _spot(u: float, v: float, sigma_px: float = 0.2, snr: float = 20.0) -> Candidate:
    return Candidate("center", np.array([u, v]), sigma_px, snr, 1.5, 0.5, 0.0)


def _group(view: float) -> FrameGroup:
    return FrameGroup([], [], ("center",), (view, 0.0))


def test_sightings_within_their_noise_join_and_a_blob_of_one_group_is_dropped() -> None:
    groups = [_group(0.0), _group(0.05), _group(0.1)]
    found = [
        (groups[0], {"center": [_spot(100.0, 50.0)]}),
        (groups[1], {"center": [_spot(100.3, 50.1), _spot(160.0, 50.0, snr=40.0)]}),  # a flicker, once
        (groups[2], {"center": [_spot(99.8, 49.9)]}),
    ]
    tracks = follow(found, ["center"])["center"]
    assert len(tracks) == 1
    (track,) = tracks
    assert track.shows_in() == 3 and track.views == {(0.0, 0.0), (0.05, 0.0), (0.1, 0.0)}
    np.testing.assert_allclose(track.pixel(), [100.033, 50.0], atol=0.01)


def test_sightings_farther_apart_than_their_noise_are_two_spots_brightest_first() -> None:
    groups = [_group(0.0), _group(0.05)]
    found = [
        (groups[0], {"center": [_spot(100.0, 50.0, snr=10.0), _spot(104.0, 50.0, snr=30.0)]}),
        (groups[1], {"center": [_spot(100.1, 50.0, snr=10.0), _spot(104.1, 50.0, snr=30.0)]}),
    ]
    tracks = follow(found, ["center"])["center"]
    assert [round(float(t.pixel()[0])) for t in tracks] == [104, 100]
    assert all(t.shows_in() == 2 for t in tracks)
    # Placed loosely (σ 1.5 px, 2.5 σ apart is 5.3 px), the same 4 px are still two spots: the join
    # stops at TRACK_JOIN_MAX_PX (3 px).
    loose = [(g, {"center": [_spot(100.0 + 4.0 * k, 50.0, sigma_px=1.5)]}) for k, g in enumerate(groups)]
    apart = follow(loose, ["center"])["center"]
    assert len(apart) == 2 and all(t.shows_in() == 1 for t in apart)


def test_a_loosely_placed_spot_joins_across_views_as_far_as_its_noise_reaches() -> None:
    """JPEG can place a faint spot 1.5 px and more apart in two views: placed to 1 px each, 2.5 px
    apart is within 2.5 σ of their difference (3.5 px, capped at 3), and one spot."""
    groups = [_group(0.0), _group(0.05)]
    found = [(g, {"center": [_spot(100.0 + 2.5 * k, 50.0, sigma_px=1.0, snr=7.0)]}) for k, g in enumerate(groups)]
    (track,) = follow(found, ["center"])["center"]
    assert track.shows_in() == 2


def test_frames_pooled_for_one_laser_tell_every_laser_that_was_on_in_them() -> None:
    """A search of the pooled frames for one laser's spot must know the others that were on: their
    spots lie in those frames too (`SpotFinder.find`'s `wanted`). Groups where the laser was off
    are left out, with their lasers."""
    a, b, c = (np.full((2, 2), k, np.uint8) for k in (1, 2, 3))
    groups = [
        FrameGroup([a], [b], ("center", "parallel"), (0.0, 0.0)),
        FrameGroup([c], [b], ("sloped",), (0.0, 0.0)),
        FrameGroup([c], [a], ("sloped", "center"), (0.05, 0.0)),
    ]
    pool = pooled_frames(groups, "center")
    assert pool is not None
    on, off, views, lit = pool
    assert [f is x for f, x in zip(on, (a, c))] == [True, True] and len(on) == 2
    assert [f is x for f, x in zip(off, (b, a))] == [True, True] and len(off) == 2
    assert views == {(0.0, 0.0), (0.05, 0.0)}
    assert lit == ["center", "parallel", "sloped"]
    assert pooled_frames(groups, "other") is None

"""Placements (angles of a silhouette from the optical axis) and the position evidence's likelihood."""

from __future__ import annotations

import math

import pytest

from models.placement import focal_px, found_placement, placement, position_log_likelihood


@pytest.mark.parametrize("shape", [(120, 160), (480, 640), (150, 200, 3)])
def test_the_image_centre_is_on_the_axis_and_angles_do_not_depend_on_the_size(shape) -> None:
    h, w = shape[:2]
    el, az, size = placement((h - 1) / 2, (w - 1) / 2, 100 * (h / 120) ** 2, shape=shape, fov_y_deg=45.0)
    assert el == pytest.approx(0.0) and az == pytest.approx(0.0)
    # 100 pixels at 160 x 120 cover the same angle as 400 at 320 x 240
    assert size == pytest.approx(math.degrees(10 / focal_px(120, 45.0)))
    # a quarter of the height up and a quarter of the width right: the same angles at every size
    el2, az2, _ = placement((h - 1) / 2 - h / 4, (w - 1) / 2 + w / 4, 1, shape=shape, fov_y_deg=45.0)
    f = focal_px(h, 45.0)
    assert el2 == pytest.approx(math.degrees(math.atan(h / 4 / f)))
    assert az2 == pytest.approx(math.degrees(math.atan(w / 4 / f)))


def test_the_top_edge_is_half_the_field_of_view_up() -> None:
    el, _, _ = placement(-0.5, 79.5, 1, shape=(120, 160), fov_y_deg=45.0)
    assert el == pytest.approx(22.5)


def test_a_found_match_scales_its_size_by_the_template_scale() -> None:
    base = placement(60, 80, 400, shape=(120, 160), fov_y_deg=45.0)
    found = found_placement((60, 80, 1.3), pixels=400, shape=(120, 160), fov_y_deg=45.0)
    assert found[:2] == pytest.approx(base[:2]) and found[2] == pytest.approx(1.3 * base[2])


@pytest.mark.parametrize(
    "residual, smaller_than",
    [
        ((0.5, 0.0, 0.0), (0.0, 0.0, 0.0)),
        ((0.0, 2.0, 0.0), (0.0, 1.0, 0.0)),
        ((0.0, 0.0, 0.3), (0.0, 0.0, 0.1)),
        ((3.0, 3.0, 0.3), (1.0, 1.0, 0.1)),
    ],
)
def test_the_likelihood_falls_with_the_residual(residual, smaller_than) -> None:
    kw = {"spread": (1.6, 1.6, 0.2), "dof": 3.0}
    assert position_log_likelihood(residual, **kw) < position_log_likelihood(smaller_than, **kw) <= 0.0
    assert position_log_likelihood((0.0, 0.0, 0.0), **kw) == 0.0


def test_heavy_tails_and_terms_left_out() -> None:
    kw = {"spread": (1.0, 1.0, 1.0), "dof": 3.0}
    # Student-t: ten spreads off costs far less than a Gaussian's 50 nats
    assert -10.0 < position_log_likelihood((10.0, None, None), **kw) < -5.0
    assert position_log_likelihood((None, None, 0.5), **kw) == position_log_likelihood((0.0, 0.0, 0.5), **kw)


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda: position_log_likelihood((0.0, 0.0), spread=(1.0, 1.0, 1.0), dof=3.0), "terms"),
        (lambda: position_log_likelihood((0.0,) * 3, spread=(1.0, 0.0, 1.0), dof=3.0), "spread"),
        (lambda: position_log_likelihood((0.0,) * 3, spread=(1.0,) * 3, dof=0.0), "dof"),
        (lambda: placement(1, 1, 0, shape=(10, 10), fov_y_deg=45.0), "pixels"),
        (lambda: placement(1, 1, 1, shape=(10, 10), fov_y_deg=180.0), "fov_y_deg"),
    ],
)
def test_bad_arguments_name_the_parameter(call, match) -> None:
    with pytest.raises(ValueError, match=match):
        call()

"""The decode plan is a pure function of the targets and the brackets: which frames a step needs, and where the AE
camera alone picks (``--parity upstream``), which frames wait for its pick."""

from __future__ import annotations

import pytest

from bracketry_emulator.ae.decode_plan import AECameraPicks, EveryCamera, FramePlan, Pick, decode_strategy

EXPS = (1000, 2000, 4000, 8000)


@pytest.mark.parametrize("parity", ["default", "upstream"])
@pytest.mark.parametrize("selection", ["highernosat", "upstream", "fusion"])
def test_the_strategy_follows_parity_selection_and_cameras(parity: str, selection: str) -> None:
    picks = parity == "upstream" and selection != "fusion"
    assert isinstance(decode_strategy(selection, parity, 2, 0), AECameraPicks if picks else EveryCamera)
    assert isinstance(decode_strategy(selection, parity, 1, 0), EveryCamera)  # one camera: nobody to pick for


def test_default_parity_decodes_the_pair_around_a_target_for_every_camera() -> None:
    plan = decode_strategy("highernosat", "default", 2, 0).plan(EXPS, [3000.0])
    assert plan == FramePlan(((0, 1), (0, 2), (1, 1), (1, 2)))
    assert decode_strategy("highernosat", "default", 2, 0).plan(EXPS, [2000.0]).frames == ((0, 1), (1, 1))
    assert decode_strategy("upstream", "default", 2, 0).plan(EXPS, [500.0]).frames == ((0, 0), (1, 0))
    assert decode_strategy("upstream", "default", 2, 0).plan(EXPS, [9000.0]).frames == ((0, 3), (1, 3))


def test_fusion_decodes_every_bracket() -> None:
    for parity in ("default", "upstream"):
        plan = decode_strategy("fusion", parity, 2, 0).plan(EXPS, [3000.0])
        assert plan == FramePlan(tuple((si, ei) for si in range(2) for ei in range(4)))


def test_several_targets_decode_the_union_once() -> None:
    plan = EveryCamera("highernosat", 2).plan(EXPS, [3000.0, 3000.0, 6000.0])
    assert plan.frames == ((0, 1), (0, 2), (0, 3), (1, 1), (1, 2), (1, 3)) and not plan.picks


def test_upstream_parity_decodes_only_the_ae_cameras_pair_and_picks_for_the_other() -> None:
    plan = decode_strategy("upstream", "upstream", 2, 0).plan(EXPS, [3000.0])
    assert plan == FramePlan(((0, 1), (0, 2)), (Pick(3000.0, ((0, 1), (0, 2)), (1,)),))
    assert plan.picks[0].frames(2) == ((1, 2),)  # the AE camera picked 4 ms: the right camera decodes that one
    assert plan.picks[0].frames(1) == ((1, 1),)


def test_upstream_parity_with_the_right_camera_as_ae_camera() -> None:
    plan = decode_strategy("highernosat", "upstream", 2, 1).plan(EXPS, [3000.0])
    assert plan == FramePlan(((1, 1), (1, 2)), (Pick(3000.0, ((1, 1), (1, 2)), (0,)),))


def test_upstream_parity_single_candidates_are_decoded_for_every_camera_without_a_pick() -> None:
    strategy = decode_strategy("upstream", "upstream", 2, 0)
    assert strategy.plan(EXPS, [500.0]) == FramePlan(((0, 0), (1, 0)))  # below the shortest bracket
    assert strategy.plan(EXPS, [9000.0]) == FramePlan(((0, 3), (1, 3)))  # above the longest
    assert decode_strategy("highernosat", "upstream", 2, 0).plan(EXPS, [4000.0]) == FramePlan(((0, 2), (1, 2)))


def test_upstream_parity_several_targets() -> None:
    plan = decode_strategy("upstream", "upstream", 2, 0).plan(EXPS, [3000.0, 500.0, 3000.0, 6000.0])
    assert plan.frames == ((0, 1), (0, 2), (0, 0), (1, 0), (0, 3))
    assert [p.target_us for p in plan.picks] == [3000.0, 6000.0]
    assert plan.picks[1].ae_frames == ((0, 2), (0, 3))

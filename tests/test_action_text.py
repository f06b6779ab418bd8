"""Both planners write an action the same way in ``Plan.actions``: ``(kind [arm] [object] [target])``,
the arm named only when the robot has more than one, a pick naming no support."""

from __future__ import annotations

import pytest

from rlgp_exec.errors import RlgpError
from rlgp_exec.planning.actions import (
    ACTION_KINDS,
    GEOMETRIC_ACTIONS,
    GNPP_ACTIONS,
    Kind,
    ground_text,
    named_arm,
    parse_text,
)
from rlgp_exec.planning.rlgp import to_actions
from rlgp_exec.planning.symbolic.model import GroundAction

#: one ground action of each kind R-LGP realises, with the PDDL domain's arguments, and how a plan writes it
GROUND = {
    Kind.PICK: (("right_arm", "block", "table"), "(pick {}block)"),
    Kind.PLACE: (("right_arm", "block", "tray"), "(place {}block tray)"),
    Kind.STACK: (("right_arm", "block", "base"), "(stack {}block base)"),
    Kind.DROP: (("right_arm", "block", "cabinet"), "(drop {}block cabinet)"),
    Kind.TAKE_KNOB: (("right_arm", "cabinet"), "(take_knob {}cabinet)"),
    Kind.OPEN_DRAWER: (("right_arm", "cabinet"), "(open_drawer {}cabinet)"),
    Kind.CLOSE_DRAWER: (("right_arm", "cabinet"), "(close_drawer {}cabinet)"),
}


def test_every_kind_is_one_member_of_the_vocabulary():
    assert [k.name for k in ACTION_KINDS] == list(Kind)
    assert set(GROUND) == set(GEOMETRIC_ACTIONS) <= set(GNPP_ACTIONS)
    assert Kind.PICK_FROM_DRAWER not in GNPP_ACTIONS and Kind.START_MOVE not in GEOMETRIC_ACTIONS


@pytest.mark.parametrize("arms", [("arm",), ("right_arm", "left_arm")])
@pytest.mark.parametrize("name", list(GROUND))
def test_rlgp_and_gnpp_write_an_action_alike(name: Kind, arms: tuple[str, ...]):
    args, form = GROUND[name]
    arm = named_arm(arms, "right_arm")
    expected = form.format("right_arm " if len(arms) > 1 else "")
    (rlgp,) = to_actions([GroundAction(name, args)])  # R-LGP: through its geometric layers' Action
    assert not isinstance(rlgp, str)
    assert rlgp.text(arm) == expected
    assert ground_text(name, args, len(arms) > 1) == expected  # GNPP: from the ground action


def test_gnpp_base_moves_name_the_arm_only_when_there_are_two():
    assert ground_text(Kind.START_MOVE, ("arm",), False) == "(start-move)"
    assert ground_text(Kind.END_MOVE, ("left_arm",), True) == "(end-move left_arm)"


@pytest.mark.parametrize("name", list(GROUND))
def test_plan_text_reads_back(name: Kind):
    args, _ = GROUND[name]
    for two in (False, True):
        w = parse_text(ground_text(name, args, two))
        assert (w.name, w.arm, w.obj) == (name, args[0] if two else None, args[1])
        assert w.target == (args[2] if len(args) > 2 and name != Kind.PICK else None)
    with pytest.raises(RlgpError, match="takes 2 words"):
        parse_text("(place a b c d)")
    with pytest.raises(RlgpError, match="unknown action kind"):
        parse_text("(fly block)")

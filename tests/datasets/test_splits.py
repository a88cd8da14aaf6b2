"""The paper's split protocol (appendix 'Dataset details') and its scaling."""

import numpy as np
import pytest

from clods_bench.datasets.splits import SplitSpec, spread
from clods_bench.errors import ClodsError


def test_paper_numbers():
    s = SplitSpec(num_train=100, num_test=20, num_steps=400, interp_steps=300, num_views_train=25, num_views_test=5)
    assert list(s.train) == list(range(100))
    assert list(s.first_half) == list(range(50))
    assert list(s.second_half) == list(range(50, 100))
    assert list(s.viewed) == list(range(50, 100))
    assert list(s.unviewed) == list(range(100, 120))
    assert list(s.interp_frames) == list(range(1, 301))
    assert list(s.extrap_frames) == list(range(301, 400))
    assert list(s.train_frames) == list(range(301))
    assert list(s.test_views) == [5, 11, 17, 23, 29]  # every 6th camera of the 30-camera ring
    assert list(s.train_views) == [v for v in range(30) if v % 6 != 5]
    subsets = s.train_mesh_subsets()
    assert list(subsets["MGN"]) == list(range(100)) and list(subsets["MGN*"]) == list(range(50))
    assert s.split_of(99) == "train" and s.split_of(100) == "test"
    with pytest.raises(ClodsError):
        s.split_of(120)


def test_defaults_are_the_paper():
    assert SplitSpec() == SplitSpec(100, 20, 400, 300, 25, 5)


def test_scaled_keeps_protocol():
    s = SplitSpec().scaled(0.1)
    assert (s.num_train, s.num_test, s.num_steps, s.interp_steps) == (10, 2, 40, 30)
    assert list(s.viewed) == list(range(5, 10)) and list(s.unviewed) == [10, 11]
    tiny = SplitSpec().scaled(0.001)
    assert tiny.num_train >= 2 and tiny.num_test >= 1 and tiny.interp_steps < tiny.num_steps - 1
    assert len(tiny.extrap_frames) >= 1
    with pytest.raises(ClodsError, match="scale"):
        SplitSpec().scaled(0)


def test_odd_num_train_halves_cover_all():
    s = SplitSpec(num_train=5, num_test=1, num_steps=10, interp_steps=5)
    assert list(s.first_half) + list(s.second_half) == list(range(5))


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"interp_steps": 400}, "interp_steps"),
        ({"interp_steps": 399}, "interp_steps"),
        ({"interp_steps": 0}, "interp_steps"),
        ({"num_train": 1}, "num_train"),
        ({"num_test": 0}, "num_test"),
        ({"num_steps": 2, "interp_steps": 1}, "num_steps"),
        ({"num_views_train": 0}, "num_views_train"),
        ({"num_views_test": -1}, "num_views_test"),
        ({"num_train": 10.0}, "num_train"),
    ],
)
def test_validation_names_field(kwargs, field):
    with pytest.raises(ClodsError) as info:
        SplitSpec(**kwargs)
    assert info.value.where == f"splits.{field}"


def test_from_data_config():
    class D:
        num_train, num_test, num_steps, interp_steps, num_cameras, num_views_test = 4, 2, 41, 30, 6, 2

    s = SplitSpec.from_data_config(D())
    assert (s.num_views_train, s.num_views_test) == (4, 2)
    assert list(s.extrap_frames) == list(range(31, 41))


@pytest.mark.parametrize("cams,held", [(6, 2), (30, 5), (8, 1), (7, 3), (5, 0), (10, 10)])
def test_held_out_cameras_are_spread_evenly_and_disjoint_from_training(cams: int, held: int):
    s = SplitSpec(num_train=4, num_test=2, num_steps=10, interp_steps=6, num_views_train=cams - held, num_views_test=held) if held < cams else None
    if s is None:  # every camera held out leaves none to fit on
        with pytest.raises(ClodsError, match="num_views_train"):
            SplitSpec(num_train=4, num_test=2, num_steps=10, interp_steps=6, num_views_train=0, num_views_test=held)
        return
    test, train = list(s.test_views), list(s.train_views)
    assert sorted(test + train) == list(range(cams)) and not set(test) & set(train)
    assert train == sorted(train) and len(test) == held
    if held:
        assert test[-1] == cams - 1  # ends on the last camera
        gaps = np.diff([-1, *test])  # cameras from one held-out view to the next: as equal as integers allow
        assert gaps.max() - gaps.min() <= 1


def test_spread_picks_every_kth_and_refuses_impossible_counts():
    assert spread(6, 2) == [2, 5] and spread(30, 5) == [5, 11, 17, 23, 29] and spread(4, 2) == [1, 3] and spread(3, 0) == []
    with pytest.raises(ClodsError, match="cannot pick 4 of 3"):
        spread(3, 4)

"""`data.same_object`: whether a dataset was recorded on the object of a material file, the
check `scripts/up.sh` makes before it trains on a dataset or serves its models."""

import tomllib

import pytest
from conftest import REPO

from haptics_train.data import same_object


def test_a_recording_is_of_the_same_object_when_its_tables_are() -> None:
    sponge = (REPO / "materials" / "sponge.toml").read_text()
    # the file as it was before it named its law: rt-loop reads it as the same foam
    unnamed = "".join(
        line for line in sponge.splitlines(keepends=True) if not line.startswith("law = ")
    )
    assert unnamed != sponge, "materials/sponge.toml names its law"
    assert same_object(unnamed, sponge)
    assert same_object(sponge, unnamed)
    assert same_object("# recorded last week\n" + sponge, sponge)
    # any value changed, another law or another file is another object
    assert "plateau_n = 2.5\n" in sponge
    assert not same_object(sponge.replace("plateau_n = 2.5\n", "plateau_n = 2.6\n"), sponge)
    assert not same_object(sponge.replace('law = "foam"', 'law = "bouc_wen"'), sponge)
    assert not same_object((REPO / "materials" / "foam-b.toml").read_text(), sponge)
    with pytest.raises(tomllib.TOMLDecodeError):
        same_object("name = [", sponge)

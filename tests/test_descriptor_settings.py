"""Descriptor options follow one pattern: a frozen settings dataclass merged with keyword arguments,
and `make_descriptor` hands radius and depth settings to every descriptor built on polar patches."""

import pytest

from geofeat.descriptors import GeoBit, GeoBitSettings, PatchSettings, make_descriptor
from geofeat.descriptors.brand import BRAND
from geofeat.descriptors.geopatch import GeoPatch
from geofeat.descriptors.geopatch_net import load_network
from geofeat.descriptors.settings import merge_settings, takes_patch_settings


def test_settings_object_dict_and_keywords_build_the_same_descriptor():
    a = GeoBit(radius=0.05, n_bits=256, depth_config="clean")
    b = GeoBit(GeoBitSettings(radius=0.05, n_bits=256, depth_config="clean"))
    c = GeoBit({"radius": 0.05, "n_bits": 256}, depth_config="clean")
    assert a.settings == b.settings == c.settings
    assert (a.radius, a.n_bits, a.depth_config) == (0.05, 256, "clean")
    assert (a.pattern == b.pattern).all()
    # keywords override the settings object
    assert GeoBit(GeoBitSettings(radius=0.05), radius=0.1).radius == 0.1


def test_bad_settings_are_refused():
    with pytest.raises(TypeError, match="unknown option.*radios"):
        GeoBit(radios=0.05)
    with pytest.raises(TypeError, match="settings"):
        GeoBit("geobit.npz")  # a positional path is not a settings object
    with pytest.raises(ValueError, match="depth_config"):
        GeoBit(depth_config="kinnect")
    with pytest.raises(ValueError, match="n_bits"):
        BRAND(n_bits=12)
    with pytest.raises(TypeError, match="unknown"):
        merge_settings(PatchSettings, {"depth": 1}, {})


def test_make_descriptor_passes_radius_and_depth_the_same_way():
    for name in ("geobit", "geopatch"):
        d = make_descriptor(name, radius=0.05, depth_config="clean")
        assert isinstance(d.settings, PatchSettings) and takes_patch_settings(type(d))
        assert (d.settings.radius, d.settings.depth_config) == (0.05, "clean")
        assert (d.radius, d.depth_config) == (0.05, "clean")
    orb = make_descriptor("orb", radius=0.05, depth_config="clean")  # no polar patches: nothing to set
    assert orb.name == "orb" and not takes_patch_settings(type(orb))
    brand = make_descriptor("brand", radius=0.05, n_bits=128)  # further options by name
    assert brand.settings.n_bits == 128 and len(brand.pattern) == 128


def test_weights_named_twice_are_refused(tmp_path):
    """make_descriptor("geopatch=A.pt", weights="B.pt") used A.pt and dropped B.pt without a word."""
    from geofeat.descriptors.geopatch import default_weights_path

    with pytest.raises(ValueError, match="give them once"):
        make_descriptor(f"geopatch={default_weights_path()}", weights=str(tmp_path / "other.pt"))


def test_descriptor_names_as_one_string_are_refused_by_name():
    """check_descriptor_names("geobit") checked its letters and said "unknown name 'g'"."""
    from geofeat.descriptors import check_descriptor_names

    with pytest.raises(ValueError, match=r"descriptors: expected a list of names such as \['geobit'\]"):
        check_descriptor_names("geobit")
    assert check_descriptor_names(["geobit", " ORB "]) == ("geobit", "orb")


@pytest.mark.parametrize("seed", [-1, 2.5, True])
def test_geobit_seed_is_a_whole_number(seed):
    """-1 and 2.5 were numpy's errors ("expected non-negative integer", "SeedSequence expects int")."""
    with pytest.raises(ValueError, match="^seed: "):
        GeoBit(seed=seed)


@pytest.mark.parametrize("option, value", [("n_rotations", True), ("n_bits", 8.0), ("n_angles", 0), ("n_rings", 2.5),
                                           ("sigma", -1.0), ("radius", "0.05"), ("radius", float("nan")),
                                           ("radius", 75.0)])
def test_geobit_settings_are_checked_by_name(option, value):
    """n_rotations=True built a GeoBit of one rotation (not rotation-invariant) without a word, a radius
    "0.05" was read as a number, NaN and 75 (millimetres) failed only when describing, n_bits=8.0 was a
    TypeError from numpy and n_angles=0 an error about n_bits."""
    with pytest.raises(ValueError, match=f"^{option}: "):
        GeoBit(**{option: value})


@pytest.mark.parametrize("make", [
    lambda: GeoPatch(weights=""),
    lambda: GeoPatch(weights="  "),
    lambda: make_descriptor("geopatch", weights=""),
    lambda: make_descriptor("tfeat-sim", weights=""),
    lambda: load_network(""),
], ids=["GeoPatch", "GeoPatch-blank", "make_descriptor", "tfeat-sim", "load_network"])
def test_an_empty_weights_path_is_refused_as_empty(make):
    """GeoPatch(weights="") read "" as the current folder and said "no GeoPatch checkpoint at .";
    None is what asks for the shipped weights, and the command line's geopatch= is refused alike."""
    with pytest.raises(ValueError, match=r"^weights: an empty path; expected the path of a weights file "
                                         r"\(None: the shipped weights\)$"):
        make()


def test_an_empty_weights_path_on_the_command_line_is_refused_as_empty(tmp_path, capsys):
    from geofeat.cli import main
    from geofeat.descriptors import check_descriptor_name

    with pytest.raises(ValueError, match=r"^descriptor: 'geopatch=': an empty path; .*"
                                         r"\(geopatch: the shipped weights\)"):
        check_descriptor_name("geopatch=")
    with pytest.raises(SystemExit) as stop:  # every command refuses an empty value before it runs (cli.main)
        main(["train", "--data", str(tmp_path), "--out", str(tmp_path / "w.pt"), "--init", ""])
    assert stop.value.code == 2
    assert "--init: an empty value (an unset shell variable?)" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []

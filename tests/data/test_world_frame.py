"""The hemisphere of a capture as a person reads it: numbers, not a repr, and no "-0"."""

from nerfaug.data.world_frame import Hemisphere, plain_number


def test_a_hemisphere_prints_as_plain_numbers():
    hemisphere = Hemisphere(centre=(6.95e-08, 0.0, -0.0), radius=4.031128, up=(0.0, -0.0, 1.0))
    text = f"{hemisphere}"
    assert text == "centre (0, 0, 0), radius 4.0311, up (0, 0, 1)"
    assert "Hemisphere(" not in text and "-0" not in text and "e-08" not in text
    assert [plain_number(v) for v in (-0.00001, 2.5, -1.23456, 1200.0)] == ["0", "2.5", "-1.2346", "1200"]

"""tests/xml_compare.py: what counts as the same document."""

from tests.xml_compare import xml_differences

BASE = '<scene><float name="near_clip" value="0.00017349424025886288"/><a x="1, 2, 3">t</a></scene>'


def test_last_digits_of_numbers_do_not_count():
    other = BASE.replace("0.00017349424025886288", "0.00017349424025886286")
    assert xml_differences(BASE, other) == []
    assert xml_differences(BASE, BASE.replace("1, 2, 3", "1.0000000000000002, 2, 3")) == []


def test_real_changes_do():
    assert xml_differences(BASE, BASE.replace("0.000173494", "0.000173495"))
    assert xml_differences(BASE, BASE.replace("1, 2, 3", "1, 2, 3.001"))
    assert xml_differences(BASE, BASE.replace("1, 2, 3", "1, 2"))
    assert xml_differences(BASE, BASE.replace('name="near_clip"', 'name="far_clip"'))
    assert xml_differences(BASE, BASE.replace("<a ", "<b ").replace("</a>", "</b>"))
    assert xml_differences(BASE, BASE.replace(">t<", ">u<"))
    assert xml_differences(BASE, BASE.replace("</scene>", "<c/></scene>"))

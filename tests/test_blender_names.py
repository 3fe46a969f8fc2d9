"""The add-on's object names (integrations/blender/names.py, standard library only), loaded from its file as
Blender loads the add-on's modules: what the user called an object, without Blender's or an exporter's additions."""

from __future__ import annotations

import importlib.util

import pytest

from tests.conftest import REPO

SPEC = importlib.util.spec_from_file_location("ctp_blender_names", REPO / "integrations/blender/names.py")
names = importlib.util.module_from_spec(SPEC)
SPEC.loader.exec_module(names)


@pytest.mark.parametrize(("name", "data_name", "sent"), [
    ("Cup", "Cylinder", "Cup"),
    ("cup.001", "cup", "cup"),  # Blender's suffix of a second "cup"
    ("coffee_cup.012", "", "coffee cup"),
    ("geometry_0", "table", "table"),  # an imported GLB's generic node: its mesh's name
    ("geometry_0.001", "geometry_0.001", None),  # nothing the user named: the service reads the file's name
    ("Mesh", "", None),
    ("Table 2", "", "Table 2"),
])
def test_object_name_is_what_the_user_called_it(name, data_name, sent):
    assert names.object_name(name, data_name) == sent

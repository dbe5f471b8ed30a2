"""One URL table: every device URL parses through it, default ports are the table's, and a URL
of the wrong role or form is one clear error naming the forms that are right."""

import re

import pytest

from spacecal.adapters import (
    DEVICE_SCHEMES,
    ROBOT,
    TRACKER,
    canonical_url,
    device_address,
    schemes_of,
)
from spacecal.core.errors import InvalidInputError


def test_every_row_names_an_adapter_with_an_opener():
    import importlib

    for scheme, row in DEVICE_SCHEMES.items():
        try:
            module = importlib.import_module(f"spacecal.adapters.{row.module}")
        except ImportError:
            continue  # its extra is not installed here
        assert callable(module.open_device), scheme
        assert row.role in (ROBOT, TRACKER) and row.form.startswith(scheme + "://")


@pytest.mark.parametrize(
    ("url", "role", "expected"),
    [
        ("ur://192.168.0.10", ROBOT, "ur://192.168.0.10"),
        ("ndi://Vega.local", TRACKER, "ndi://vega.local:8765"),
        ("ndi://10.0.0.5:9000", TRACKER, "ndi://10.0.0.5:9000"),
        ("ndi:///dev/ttyUSB0", TRACKER, "ndi:///dev/ttyUSB0"),
        ("igtl://PlusHost", TRACKER, "igtl://plushost:18944"),
        # the query is the natnet adapter's (its rigid body), kept as given; others have none
        ("natnet://Motive-PC?body=Marker", TRACKER, "natnet://motive-pc:1510?body=Marker"),
        ("natnet://10.0.0.7:1600", TRACKER, "natnet://10.0.0.7:1600"),
        ("igtl://PlusHost?body=Marker", TRACKER, "igtl://plushost:18944"),
        # a camera: a device index, or a folder whose path keeps its case; the query its adapter's
        ("camera://0?board=b.json", TRACKER, "camera://0?board=b.json"),
        (
            "camera:///data/Views?mount=flange&board=B.json",
            TRACKER,
            "camera:///data/Views?board=B.json&mount=flange",
        ),
        ("camera:Views/Run1?board=b.json", TRACKER, "camera:Views/Run1?board=b.json"),
    ],
)
def test_urls_take_the_tables_default_ports(url, role, expected):
    assert device_address(url, role).url == expected
    assert canonical_url(url) == expected


@pytest.mark.parametrize(
    ("url", "role", "message"),
    [
        ("ndi://vega", ROBOT, "expected ur://HOST, franka://HOST, ros2://HOST[:PORT]?joints=... or sim"),
        (
            "ur://robot",
            TRACKER,
            "expected ndi://SERIAL_PORT_OR_HOST[:PORT], igtl://HOST[:PORT], "
            "natnet://HOST[:PORT]?body=RIGID_BODY, "
            "camera://DEVICE_OR_FOLDER?board=FILE[&intrinsics=FILE] or sim",
        ),
        ("igtl://", TRACKER, "names no host"),
        ("igtl://host:99999", TRACKER, "invalid port"),
        ("http://host", None, "expected ur://HOST"),
    ],
)
def test_a_url_of_the_wrong_kind_is_one_clear_error(url, role, message):
    with pytest.raises(InvalidInputError, match=re.escape(message)) as caught:
        device_address(url, role)
    assert "\n" not in str(caught.value)


def test_a_natnet_url_is_the_same_device_whatever_the_order_of_its_query():
    assert canonical_url("natnet://Motive?tools=Pointer&body=Marker") == canonical_url(
        "natnet://motive:1510?body=Marker&tools=Pointer"
    )
    assert canonical_url("natnet://motive?body=Marker") != canonical_url("natnet://motive?body=Other")


def test_roles_partition_the_table():
    assert set(schemes_of(ROBOT)) | set(schemes_of(TRACKER)) == set(DEVICE_SCHEMES)
    assert not set(schemes_of(ROBOT)) & set(schemes_of(TRACKER))

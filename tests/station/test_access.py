"""Who may talk to the station: loopback by default; another interface only with a token, and
then every request without it is refused; forms from other sites' pages are refused."""

from __future__ import annotations

import pytest

from spacecal.cli.main import main
from spacecal.core.errors import InvalidInputError
from tests.station.conftest import need


def client(tmp_path, host="127.0.0.1", token=None):
    testclient = need("starlette.testclient")
    from spacecal.station.server import StationOptions, build

    station, application = build(StationOptions(host=host, token=token, data=str(tmp_path / "station")))
    return station, testclient.TestClient(application, base_url=f"http://{host}:8770")


def test_the_station_listens_on_loopback_unless_told_otherwise():
    need("starlette")
    from spacecal.station.server import StationOptions

    assert StationOptions().host == "127.0.0.1"
    from spacecal.cli.parser import build_parser

    args = build_parser({name: None for name in _commands()}).parse_args(["station"])
    assert args.host == "127.0.0.1" and args.token_file is None and not hasattr(args, "token")


def _commands():
    from spacecal.cli.main import COMMANDS

    return COMMANDS


def test_another_interface_needs_a_token(tmp_path, capsys):
    need("starlette")
    from spacecal.station.access import check_bind

    for host in ("0.0.0.0", "192.168.1.20", "::"):
        with pytest.raises(InvalidInputError, match="only with an access token"):
            check_bind(host, None)
    check_bind("127.0.0.1", None)
    check_bind("localhost", None)
    with pytest.raises(InvalidInputError, match="16 to 256 characters"):
        check_bind("0.0.0.0", "short")
    assert main(["station", "--host", "0.0.0.0", "--data", str(tmp_path)]) == 1
    err = capsys.readouterr().err
    assert "only with an access token" in err and err.count("\n") == 1


def test_requests_without_the_token_are_refused(tmp_path):
    token = "a-long-enough-token-1234"
    station, web = client(tmp_path, host="192.168.1.20", token=token)
    try:
        assert web.get("/").status_code == 401
        assert web.get("/", headers={"X-Station-Token": "wrong-token-wrong-token"}).status_code == 401
        assert web.post("/devices", data={"kind": "robot", "name": "r", "url": "sim"}).status_code == 401
        assert station.ledger.robots() == []
        # an address carrying the token: the browser keeps it in a cookie
        opened = web.get(f"/?token={token}")
        assert opened.status_code == 200
        assert web.get("/").status_code == 200
        assert web.post("/devices", data={"kind": "robot", "name": "r", "url": "sim"}).status_code == 200
        assert [r["name"] for r in station.ledger.robots()] == ["r"]
    finally:
        station.ledger.close()


def test_on_loopback_other_host_names_and_other_sites_forms_are_refused(tmp_path):
    station, web = client(tmp_path)
    try:
        assert web.get("/").status_code == 200
        # a site that rebinds its own name to 127.0.0.1
        assert web.get("/", headers={"Host": "evil.example:8770"}).status_code == 421
        # a form posted from another site's page
        refused = web.post(
            "/devices",
            data={"kind": "robot", "name": "x", "url": "sim"},
            headers={"Origin": "http://evil.example"},
        )
        assert refused.status_code == 403 and station.ledger.robots() == []
    finally:
        station.ledger.close()


def test_untrusted_names_are_escaped(tmp_path):
    station, web = client(tmp_path)
    try:
        name = '<script>alert("x")</script>'
        web.post("/devices", data={"kind": "robot", "name": name, "url": "sim"})
        page = web.get("/").text
        assert name not in page and "&lt;script&gt;alert(" in page
    finally:
        station.ledger.close()


def test_station_without_the_extra_is_one_line(monkeypatch, capsys):
    import builtins

    real_import = builtins.__import__

    def no_station(name, *args, **kwargs):
        if name.startswith("spacecal.station") or name in ("uvicorn", "starlette", "sqlalchemy"):
            raise ImportError(f"No module named {name!r}")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_station)
    assert main(["station"]) == 1
    err = capsys.readouterr().err
    assert (
        err == "spacecal: error: spacecal station needs the station extra: pip install 'spacecal[station]'\n"
    )


def test_the_trend_figure_cannot_close_its_script_element():
    need("starlette")
    import json

    from spacecal.station.web import script_json

    text = script_json({"name": "</script><script>alert(1)</script> & more"})
    assert "<" not in text and ">" not in text and "&" not in text
    assert json.loads(text) == {"name": "</script><script>alert(1)</script> & more"}


def test_the_core_and_the_command_line_import_without_the_station_extra():
    import subprocess
    import sys

    blocked = ("sqlalchemy", "starlette", "uvicorn", "jinja2", "psycopg", "playwright", "multipart")
    code = (
        "import sys\n"
        "class Block:\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        f"        if name.split('.')[0] in {blocked!r}:\n"
        "            raise ImportError(name)\n"
        "sys.meta_path.insert(0, Block())\n"
        "import spacecal.app\n"
        "from spacecal.cli.main import main\n"
        "sys.exit(main(['station']))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 1, done.stderr
    assert done.stderr == (
        "spacecal: error: spacecal station needs the station extra: pip install 'spacecal[station]'\n"
    )

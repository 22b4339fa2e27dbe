"""A unit's keys are checked before anything starts (runtime/transport/security.py,
``check_credentials``), and kept on disk as ssh keeps its own (runtime/transport/keygen.py).

Each bad key file gives exit 1 and one line naming the file and the reason, through the
real command (``ctrlunit start ... --keys DIR --check``, a subprocess) and through the
function; ``keys init`` sets its modes whatever the umask and keeps the authority's key
apart; keys others can read and a keys directory others can write are refused."""

from __future__ import annotations

import datetime
import os
import shutil
import stat
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

START = ["start", "--peripherals", "3", "--pipeline", "2", "--clock", "lockstep", "--check"]
ROLES = ["central", "plant", "peripheral-1", "peripheral-2", "peripheral-3"]
"""The roles that ``START`` runs, whose credentials it checks."""


def now() -> datetime.datetime:
    """The time of the check: read when it runs, not when the module was collected (the
    keys are made later, valid from five minutes before they were made)."""
    return datetime.datetime.now(datetime.UTC)


def ctrlunit(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "ctrlunit.runtime.cli", *args],
                          capture_output=True, text=True, timeout=120)


@pytest.fixture(scope="module")
def made(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A unit's keys as ``keys init`` writes them (``unit`` and ``unit-authority``)."""
    from ctrlunit.runtime.transport.security import make_keys

    root = tmp_path_factory.mktemp("made")
    make_keys(root / "unit")
    return root


@pytest.fixture
def keys(made: Path, tmp_path: Path) -> Path:
    """A fresh copy of the unit's keys (modes kept) for one test to spoil."""
    shutil.copytree(made / "unit", tmp_path / "keys")
    shutil.copytree(made / "unit-authority", tmp_path / "keys-authority")
    return tmp_path / "keys"


def replace(path: Path, data: bytes) -> None:
    """Write ``data`` over ``path``, keeping its mode (as a copy over it would)."""
    path.write_bytes(data)


def expired(keys: Path) -> None:
    """central.pem replaced by one for central's own key, signed by the unit's authority,
    valid through 2025 only."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization

    auth = keys.with_name(keys.name + "-authority")
    ca_key = serialization.load_pem_private_key((auth / "ca.key").read_bytes(), None)
    ca = x509.load_pem_x509_certificate((keys / "ca.pem").read_bytes())
    old = x509.load_pem_x509_certificate((keys / "central.pem").read_bytes())
    cert = (x509.CertificateBuilder().subject_name(old.subject).issuer_name(ca.subject)
            .public_key(old.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(datetime.datetime(2025, 1, 1, tzinfo=datetime.UTC))
            .not_valid_after(datetime.datetime(2026, 1, 1, tzinfo=datetime.UTC))
            .sign(ca_key, hashes.SHA256()))
    replace(keys / "central.pem", cert.public_bytes(serialization.Encoding.PEM))


def as_other(keys: Path, role: str, other: str) -> None:
    """``other``'s key and certificate in ``role``'s place."""
    for ext in ("pem", "key"):
        replace(keys / f"{role}.{ext}", (keys / f"{other}.{ext}").read_bytes())


def foreign(keys: Path) -> None:
    """plant.pem and plant.key of another unit (its authority has the same name)."""
    from ctrlunit.runtime.transport.security import make_keys

    make_keys(keys.parent / "other")
    as_other(keys, "plant", "../other/plant")


SPOILED: dict[str, tuple[Callable[[Path], None], str]] = {
    "truncated central.key": (
        lambda k: replace(k / "central.key", (k / "central.key").read_bytes()[:100]),
        "central.key is not a readable PEM private key"),
    "garbage plant.key": (
        lambda k: replace(k / "plant.key", b"garbage\n" * 10),
        "plant.key is not a readable PEM private key"),
    "a key that is not its certificate's": (
        lambda k: replace(k / "plant.key", (k / "central.key").read_bytes()),
        "plant.key does not match plant.pem (the certificate's public key differs)"),
    "the viewer's certificate in the plant's place": (
        lambda k: as_other(k, "plant", "viewer"),
        "plant.pem is the certificate of 'viewer' (its common name), not of plant"),
    "only the viewer's certificate in the plant's place": (
        lambda k: replace(k / "plant.pem", (k / "viewer.pem").read_bytes()),
        "plant.pem is the certificate of 'viewer' (its common name), not of plant"),
    "an expired certificate": (expired, "central.pem expired on 2026-01-01 00:00 UTC"),
    "peripheral-2's certificate as peripheral-1's": (
        lambda k: as_other(k, "peripheral-1", "peripheral-2"),
        "peripheral-1.pem is the certificate of 'peripheral-2' (its common name), not of "
        "peripheral-1"),
    "a missing .pem": (lambda k: (k / "peripheral-3.pem").unlink(),
                       "peripheral-3.pem is missing"),
    "another unit's certificate": (
        foreign, "plant.pem is not signed by the authority of ca.pem"),
    "a truncated ca.pem": (
        lambda k: replace(k / "ca.pem", (k / "ca.pem").read_bytes()[:200]),
        "ca.pem is not a readable PEM certificate"),
    "a role's certificate as ca.pem": (
        lambda k: replace(k / "ca.pem", (k / "viewer.pem").read_bytes()),
        "ca.pem is not a certificate authority's"),
}


def one_line(res: subprocess.CompletedProcess[str]) -> str:
    """The command's only line on stderr, with exit 1."""
    assert res.returncode == 1, (res.returncode, res.stdout, res.stderr)
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("ctrlunit: error: --keys "), res.stderr
    assert "Traceback" not in res.stderr
    return lines[0]


@pytest.mark.parametrize("case", list(SPOILED))
def test_a_bad_key_file_stops_start_before_anything_starts(keys, case):
    spoil, reason = SPOILED[case]
    spoil(keys)
    line = one_line(ctrlunit(*START, "--keys", str(keys)))
    assert f"--keys {keys}: {reason}" in line, line


@pytest.mark.parametrize("case", list(SPOILED))
def test_the_check_names_the_file_and_the_reason(keys, case):
    from ctrlunit.runtime.transport.security import check_credentials

    check_credentials(keys, ROLES, now=now())  # the unit's keys as made pass
    spoil, reason = SPOILED[case]
    spoil(keys)
    with pytest.raises(ValueError) as err:
        check_credentials(keys, ROLES, now=now())
    assert str(err.value) == f"--keys {keys}: {reason}" or \
        str(err.value).startswith(f"--keys {keys}: {reason} ("), err.value
    assert "\n" not in str(err.value)


def test_the_validity_is_read_at_the_time_given(keys):
    from ctrlunit.runtime.transport.security import check_credentials

    with pytest.raises(ValueError, match=r"ca\.pem is valid only from .* UTC \(is this "
                       "host's clock right\\?\\)"):
        check_credentials(keys, ["central"], now=now() - datetime.timedelta(days=1))
    with pytest.raises(ValueError, match=r"ca\.pem expired on "):
        check_credentials(keys, ["central"], now=now() + datetime.timedelta(days=366))


def test_each_role_checks_its_own_files_only(keys):
    """A role's host holds ca.pem and its role's two files: that is enough for it, and
    its own bad or missing files stop it."""
    for f in keys.iterdir():
        if f.name not in ("ca.pem", "peripheral-2.pem", "peripheral-2.key", "plant.pem",
                          "plant.key"):
            f.unlink()
    ok = ctrlunit("peripheral", "--index", "2", "--unit", "u", "--keys", str(keys), "--check")
    assert ok.returncode == 0, ok.stderr
    assert "peripheral-1.pem is missing" in one_line(
        ctrlunit("peripheral", "--index", "1", "--unit", "u", "--keys", str(keys), "--check"))
    replace(keys / "plant.key", b"garbage\n")
    assert "plant.key is not a readable PEM private key" in one_line(
        ctrlunit("plant", "--unit", "u", "--keys", str(keys), "--check"))
    assert "central.pem is missing" in one_line(
        ctrlunit("central", "--listen", "tcp/127.0.0.1:7447", "--keys", str(keys), "--check"))


def test_keys_init_under_umask_000_sets_the_modes_and_keeps_the_authority_apart(tmp_path):
    old = os.umask(0)
    try:
        res = ctrlunit("keys", "init", str(tmp_path / "k"), "--peripherals", "1")
    finally:
        os.umask(old)
    assert res.returncode == 0, res.stderr
    auth = tmp_path / "k-authority"
    assert f"the authority's key into {auth / 'ca.key'}" in res.stdout
    mode = {p.name: stat.S_IMODE(p.stat().st_mode) for p in (tmp_path / "k").iterdir()}
    assert stat.S_IMODE((tmp_path / "k").stat().st_mode) == 0o700
    assert stat.S_IMODE(auth.stat().st_mode) == 0o700
    assert "ca.key" not in mode
    assert {n: m for n, m in mode.items() if n.endswith(".key")} == {
        f"{r}.key": 0o600 for r in ("central", "plant", "peripheral-1", "viewer")}
    assert {m for n, m in mode.items() if n.endswith(".pem")} == {0o644}
    assert stat.S_IMODE((auth / "ca.key").stat().st_mode) == 0o600
    assert (auth / "ca.pem").read_bytes() == (tmp_path / "k" / "ca.pem").read_bytes()


def test_keys_init_keeps_an_existing_folder_s_mode_and_refuses_one_others_may_write(
        tmp_path):
    """An existing folder is the user's: ``keys init`` made a 0755 one 0700 (a review);
    now it keeps its mode, and one others may write is refused before anything is
    written, naming the fix."""
    shared, open_ = tmp_path / "shared", tmp_path / "open"
    shared.mkdir(mode=0o755)
    open_.mkdir()
    open_.chmod(0o777)
    res = ctrlunit("keys", "init", str(shared), "--peripherals", "1")
    assert res.returncode == 0, res.stderr
    assert stat.S_IMODE(shared.stat().st_mode) == 0o755
    assert stat.S_IMODE((shared / "central.key").stat().st_mode) == 0o600
    res = ctrlunit("keys", "init", str(open_), "--peripherals", "1")
    assert res.returncode == 1 and f"{open_} can be written by others (mode 0777)" in \
        res.stderr and f"chmod 700 {open_}" in res.stderr, res.stderr
    assert not list(open_.iterdir()) and not (tmp_path / "open-authority").exists()


def test_keys_init_refuses_before_writing_what_the_run_would_refuse(tmp_path):
    """An attacker's review: a link to nothing in the folder stopped keys init half-way
    (an errno, ca.pem written, the authority's key lost when the link was its), and a
    folder under one others may write, or another user's, was filled with keys every
    run then refused. Each is now refused before any file is written."""
    (tmp_path / "open").mkdir()
    (tmp_path / "open").chmod(0o777)
    res = ctrlunit("keys", "init", str(tmp_path / "open" / "k"), "--peripherals", "1")
    assert res.returncode == 1 and "which others can write (mode 0777)" in res.stderr, \
        res.stderr
    assert not (tmp_path / "open" / "k").exists()
    for where in ("k", "k-authority"):
        d = tmp_path / f"link-{where}"
        keys = tmp_path / "link-k"
        d.mkdir(mode=0o700, exist_ok=True)
        keys.mkdir(mode=0o700, exist_ok=True)
        name = "ca.key" if where == "k-authority" else "central.key"
        (d / name).symlink_to(tmp_path / f"nothing-{where}")
        res = ctrlunit("keys", "init", str(keys), "--peripherals", "1")
        assert res.returncode == 1 and f"{d / name} exists" in res.stderr, res.stderr
        assert sorted(p.name for p in keys.iterdir()) == (
            [] if where == "k-authority" else ["central.key"])  # nothing written
        assert not (tmp_path / f"nothing-{where}").exists()  # nor through the link
        (d / name).unlink()
    if os.geteuid() == 0:  # another user's folder: only root can make one here
        other = tmp_path / "other"
        other.mkdir(mode=0o700)
        os.chown(other, 65534, 65534)
        res = ctrlunit("keys", "init", str(other), "--peripherals", "1")
        assert res.returncode == 1 and "belongs to another user" in res.stderr, res.stderr
        assert not list(other.iterdir())


def test_keys_init_never_overwrites_the_authority(tmp_path):
    auth = tmp_path / "safe"
    auth.mkdir()
    (auth / "ca.key").write_text("the authority of another unit")
    res = ctrlunit("keys", "init", str(tmp_path / "k"), "--authority", str(auth))
    assert res.returncode == 1 and f"{auth / 'ca.key'} exists" in res.stderr, res.stderr
    assert (auth / "ca.key").read_text() == "the authority of another unit"
    assert not (tmp_path / "k").exists()  # nothing written
    res = ctrlunit("keys", "init", str(tmp_path / "k"), "--authority", str(tmp_path / "k"))
    assert res.returncode == 1 and "kept apart" in res.stderr, res.stderr


OPEN: dict[str, tuple[Callable[[Path], None], str]] = {
    "a key others can read": (lambda k: (k / "plant.key").chmod(0o644),
                              "plant.key is open to others (mode 0644; a private key must be "
                              "its owner's alone): chmod 600 {k}/plant.key"),
    "a key its group can write": (lambda k: (k / "central.key").chmod(0o620),
                                  "central.key is open to others (mode 0620"),
    "a keys directory its group can write": (
        lambda k: k.chmod(0o770), "{k} can be written by others (mode 0770), who could "
        "replace the unit's keys: chmod 700 {k}"),
    "a ca.pem others can write": (lambda k: (k / "ca.pem").chmod(0o666),
                                  "ca.pem can be written by others (mode 0666), who could "
                                  "replace it: chmod 644 {k}/ca.pem"),
    "a certificate others can write": (lambda k: (k / "peripheral-2.pem").chmod(0o646),
                                       "peripheral-2.pem can be written by others (mode "
                                       "0646)"),
    "the authority's key in the keys directory": (
        lambda k: shutil.copy2(k.with_name(k.name + "-authority") / "ca.key", k),
        "ca.key is there, the authority's private key: no role needs it"),
}


@pytest.mark.parametrize("case", list(OPEN))
def test_keys_others_can_read_or_replace_are_refused(keys, case):
    from ctrlunit.runtime.transport.security import check_credentials

    spoil, reason = OPEN[case]
    spoil(keys)
    expected = f"--keys {keys}: " + reason.format(k=keys)
    line = one_line(ctrlunit(*START, "--keys", str(keys)))
    assert expected in line, line
    with pytest.raises(ValueError) as err:
        check_credentials(keys, ROLES, now=now())
    assert str(err.value).startswith(expected), err.value


def test_a_missing_keys_directory_names_ca_pem_as_before(tmp_path):
    line = one_line(ctrlunit(*START, "--keys", str(tmp_path / "none")))
    assert line.endswith(f"--keys {tmp_path / 'none'}: no ca.pem there (make a unit's keys "
                         "with: ctrlunit keys init DIR)")


def test_keys_whose_folder_or_link_target_others_may_write_are_refused(keys, tmp_path):
    """An attacker's review: ``ca.pem`` and ``plant.key`` as symbolic links to files in a
    folder anyone may write, and a keys folder inside such a folder, passed the checks;
    whoever may write there can put another authority in place. Every folder above each
    file (through a link: its target's) must be writable by its owner alone, unless it
    has the sticky bit (as /tmp); a role's file that is a folder is not "missing"."""
    from ctrlunit.runtime.transport.keycheck import check_credentials

    check_credentials(keys, ROLES, now=now())  # tmp_path lies under /tmp: sticky, allowed
    public = tmp_path / "public"
    public.mkdir()
    public.chmod(0o777)
    for name in ("ca.pem", "plant.key"):
        spoiled = tmp_path / f"spoiled-{name}"
        shutil.copytree(keys, spoiled)
        target = public / name
        shutil.copy2(spoiled / name, target)
        (spoiled / name).unlink()
        (spoiled / name).symlink_to(target)
        with pytest.raises(ValueError, match=rf"{name} lies in {public}, which others can "
                                             r"write \(mode 0777\).*chmod go-w"):
            check_credentials(spoiled, ROLES, now=now())
    inside = public / "keys"
    shutil.copytree(keys, inside)
    with pytest.raises(ValueError, match=f"ca.pem lies in {public}, which others can write"):
        check_credentials(inside, ROLES, now=now())
    public.chmod(0o1777)  # sticky: no one else may replace what is in it
    check_credentials(inside, ROLES, now=now())
    (keys / "plant.key").unlink()
    (keys / "plant.key").mkdir()
    with pytest.raises(ValueError, match="plant.key is not a regular file"):
        check_credentials(keys, ROLES, now=now())

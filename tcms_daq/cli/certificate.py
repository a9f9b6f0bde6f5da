"""``tcms certificate RUN_ID``: the PDF test certificate of a stored run (as ``GET /api/tests/{id}/certificate.pdf``)."""

from __future__ import annotations

import argparse
from pathlib import Path

from tcms_daq.errors import DataFormatError
from tcms_daq.settings import DEFAULT_DATA_DIR, read_settings


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "certificate",
        help="write the PDF test certificate of a stored run",
        description="Write the test certificate of a stored run as PDF: identity, parameters, the hysteresis "
        "curve, results ± U with the decision rule, verdict, instruments and their calibration, compensation "
        "version. Reads the run store beside a running service without changing it.",
    )
    p.add_argument("run_id", metavar="RUN_ID", help="id of a stored test run")
    p.add_argument("--data-dir", type=Path, default=None,
                   help=f"data directory of the SQLite run store (default: $TCMS_DATA_DIR or ./{DEFAULT_DATA_DIR})")
    p.add_argument("--store", metavar="URL", default=None,
                   help="run store URL, e.g. postgresql://user@host/db (default: $TCMS_STORE_URL, else --data-dir)")
    p.add_argument("--lang", choices=("en", "zh"), default="en",
                   help="language of the certificate: en (English) or zh (Simplified Chinese; needs a CJK font)")
    p.add_argument("-o", "--output", type=Path, default=None,
                   help="PDF file to write (default: ./tcms-certificate-RUN_ID.pdf)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from tcms_daq.service.certificate import render_certificate
    from tcms_daq.store import StoreError, open_store
    from tcms_daq.store.opening import sqlite_path, store_kind

    env = read_settings()
    url = args.store or env.store_url
    data_dir = Path(args.data_dir or env.data_dir)
    try:
        if store_kind(url) == "sqlite" and not sqlite_path(url, data_dir).is_file():
            raise DataFormatError(f"no run store at {sqlite_path(url, data_dir)} (give --data-dir or --store)")
        store = open_store(url, data_dir, recover=False)
    except StoreError as exc:
        raise DataFormatError(str(exc)) from None
    try:
        record = store.get_run(args.run_id)
        if record is None:
            raise DataFormatError(f"unknown run {args.run_id!r} in {store.describe()}")
        pdf = render_certificate(record, store.read_columns(record.id), lang=args.lang)
    finally:
        store.close()
    out = args.output or Path(f"tcms-certificate-{record.id}.pdf")
    try:
        out.write_bytes(pdf)
    except OSError as exc:
        raise DataFormatError(f"{out}: cannot write ({exc.strerror or exc})") from None
    print(f"wrote {out} (certificate of run {record.id}, {record.status})")
    return 0

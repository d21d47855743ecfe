"""
emfc-bag-repair: make a bag whose recorder was killed, or whose files are damaged, readable.

``emfc-bag-repair BAG_DIR [--no-backup]`` checks every chunk's CRC of every storage file and
recovers every intact MCAP record of each damaged file (a killed recorder leaves its last
file without summary and footer; a corrupt chunk is skipped and reported with its byte
offset, time range and messages lost), rewrites those files as valid MCAP (the original kept
as ``<file>.damaged`` unless ``--no-backup``) and rebuilds ``metadata.yaml`` from all storage
files, keeping its ``custom_data``. Intact files are not rewritten, so running it on a good
bag is harmless. Exit code 0 on success (the summary says what was lost), 2 if the folder is
not a bag.
"""

from __future__ import annotations

import argparse
from pathlib import Path
import sys
from typing import List, Optional

from emfc_ros.core.bag.errors import BagFormatError
from emfc_ros.core.bag.repair import repair_bag


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog='emfc-bag-repair',
        description='Recover the intact records of a killed recording or damaged bag and '
                    'rebuild metadata.yaml (rosbag2 version 9, MCAP storage).')
    parser.add_argument('bag', type=Path, help='bag folder (holding metadata.yaml and *.mcap)')
    parser.add_argument('--no-backup', action='store_true',
                        help='delete damaged originals instead of keeping <file>.damaged')
    return parser


def main(argv: Optional[List[str]] = None) -> int:
    """
    Run the command.

    Parameters
    ----------
    argv : list of str, optional
        Arguments (``sys.argv[1:]`` when absent).

    Returns
    -------
    int
        Exit code: 0 on success, 2 if the folder is not a bag.
    """
    args = _parser().parse_args(argv)
    try:
        report = repair_bag(args.bag, keep_damaged=not args.no_backup)
    except (BagFormatError, OSError) as exc:
        print(f'emfc-bag-repair: {exc}', file=sys.stderr)
        return 2
    print(report.summary())
    return 0


if __name__ == '__main__':
    raise SystemExit(main())

"""
emfc-bag-info: summarise a bag like ``ros2 bag info``, without ROS.

``emfc-bag-info BAG_DIR [--check] [--streams]`` prints the files, size, duration, topics with
types and counts, the custom data keys; with ``--check`` (implied by ``--streams``) whether
every chunk's CRC is intact, listing corrupt chunks (byte offset, time range, messages lost);
with ``--streams`` each block stream's sample rate, channels, sample range and gaps (the
blocks of corrupt chunks are gaps). Exit code 2 if the bag cannot be read (for a killed
recording, run ``emfc-bag-repair`` first).
"""

from __future__ import annotations

import argparse
from pathlib import Path
import sys
from typing import List, Optional

from emfc_ros.core.bag.errors import BagFormatError
from emfc_ros.core.bag.info import bag_info


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
        Exit code: 0 on success, 2 if the bag cannot be read.
    """
    parser = argparse.ArgumentParser(prog='emfc-bag-info',
                                     description='Summarise a rosbag2 bag without ROS.')
    parser.add_argument('bag', type=Path, help='bag folder')
    parser.add_argument('--check', action='store_true',
                        help='also check every chunk (CRC) and list the corrupt ones')
    parser.add_argument('--streams', action='store_true',
                        help='also read and describe the block streams (implies --check)')
    args = parser.parse_args(argv)
    try:
        print(bag_info(args.bag, streams=args.streams, check=args.check))
    except (BagFormatError, OSError, ValueError, KeyError) as exc:
        print(f'emfc-bag-info: {exc}', file=sys.stderr)
        return 2
    return 0


if __name__ == '__main__':
    raise SystemExit(main())

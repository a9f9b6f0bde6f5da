import sys

from tcms_daq.cli import main

sys.exit(main())

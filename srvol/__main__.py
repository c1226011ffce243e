import sys

from srvol.cli import main

sys.exit(main())

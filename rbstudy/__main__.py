import sys

from rbstudy.cli import main

sys.exit(main())

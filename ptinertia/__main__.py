import sys

from ptinertia.cli import main

sys.exit(main())

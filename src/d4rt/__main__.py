import sys

from d4rt.cli import main

sys.exit(main())

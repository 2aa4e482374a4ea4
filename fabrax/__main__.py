import sys

from fabrax.cli import main

sys.exit(main())

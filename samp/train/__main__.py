import sys

from samp.train.cli import main

sys.exit(main())

import sys

from samp.train.recipe import main

sys.exit(main())

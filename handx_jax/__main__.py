import sys

from handx_jax.cli import main

sys.exit(main())

"""`python -m ngpm_compiler.cli`: the same as `ngpmc`."""

import sys

from ngpm_compiler.cli import main

sys.exit(main())

"""``python -m drake_contact`` is the ``drake-contact`` command."""

import sys

from drake_contact.app.cli import main

sys.exit(main())

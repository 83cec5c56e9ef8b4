"""drake_contact: Kiguchi (1993) force control in contact with compliant
environments, reproduced as Drake systems-framework diagrams.

Start at :func:`drake_contact.diagram.MakeContactDiagram` (the diagram) and
:func:`drake_contact.runner.run` (simulate one scenario and write its logs).
"""

__version__ = "0.1.0"

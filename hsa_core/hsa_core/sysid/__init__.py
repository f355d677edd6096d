"""System identification: excitation, constants, rest strains, open-loop verification and the
world's static mismatch at rest."""

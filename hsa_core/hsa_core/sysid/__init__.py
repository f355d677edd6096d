"""System identification: excitation, constants, rest strains and open-loop verification."""

"""One cable: its path (straight or over a swivel pulley), the cable laws, the elastic catenary and
the dynamic stiffness of one cable. Imports core and io."""

"""Statics of a CDPR: geometry and structure matrix, inverse statics, the residuals and root finding
of forward statics, and the static pose error with sagging cables. Imports core, io and cable."""

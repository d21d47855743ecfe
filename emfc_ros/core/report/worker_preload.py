"""
First module the plot workers' fork server imports: scipy's docstring rewriting skipped.

Imported for its effect (:func:`emfc_ros.core.scipy_docs.skip_docstring_notes`) before the
server imports the identification and plotting modules (:func:`background._context`).
"""

from emfc_ros.core.scipy_docs import skip_docstring_notes

APPLIED = skip_docstring_notes()

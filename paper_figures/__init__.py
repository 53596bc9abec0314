"""One script per paper figure; each module has ``make(out_dir, quick=False, *, context=None) -> [paths]``.

``FIGURES`` maps the short name used by ``virheo figures --only`` to the module, in the paper's order.
"""

FIGURES = {
    "fig02": "paper_figures.fig02_1d_model",
    "fig03": "paper_figures.fig03_elastic_moduli",
    "fig04": "paper_figures.fig04_flow_rules",
    "fig05": "paper_figures.fig05_simple_shear",
    "fig06": "paper_figures.fig06_landscapes",
    "fig07": "paper_figures.fig07_views",
    "fig09": "paper_figures.fig09_conditioning",
    "fig10": "paper_figures.fig10_setups_error",
    "fig13": "paper_figures.fig13_table1_real",
}
SIMULATION_FREE = ("fig02", "fig05")  # make() ignores the context

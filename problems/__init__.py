"""Built-in problems, one module per scene, each with ``make(**overrides) -> pdeinv.Problem``.

This folder is installed as the subpackage ``pdeinv.problems`` (meshes included, see
``pyproject.toml``), so ``pdeinv.load_problem("heat_1d")`` finds these modules from any
folder and in a non-editable install. Copy one as the start of your own problem.
"""

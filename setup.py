"""The recipes (tasks/*.yaml) ship inside the `agents` package as agents/tasks/*.yaml, where
`agents.recipes.recipe_dirs` finds them in an installed wheel. The source tree keeps them at the
top level, where users and branches edit them; everything else is in pyproject.toml."""
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

ROOT = Path(__file__).resolve().parent


class BuildWithRecipes(build_py):
    def run(self):
        super().run()
        if self.editable_mode:  # an editable install reads tasks/ in the checkout
            return
        target = Path(self.build_lib) / "agents" / "tasks"
        target.mkdir(parents=True, exist_ok=True)
        for recipe in sorted((ROOT / "tasks").glob("*.yaml")):
            self.copy_file(str(recipe), str(target / recipe.name))


setup(cmdclass={"build_py": BuildWithRecipes})

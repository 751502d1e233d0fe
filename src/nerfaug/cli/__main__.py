"""`python -m nerfaug.cli`: the `nerfaug` command where its script is not on the PATH."""

from nerfaug.cli import main

main()

"""``python -m voe_lightning fit|validate|test|generate|analyze ...``"""

from voe_lightning.cli import main

if __name__ == "__main__":
    main()

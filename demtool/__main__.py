from demtool.cli import main

main()

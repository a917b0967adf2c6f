from hikoboshi.cli import main

main()
